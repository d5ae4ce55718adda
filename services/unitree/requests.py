"""Requests to the adapter's RPC services (the motion switcher, the sport service): a bounded intake.

A request costs the adapter the binding's decode and a Response_ write, about a millisecond of
GIL-held Python together, on the DDS thread that also reads rt/lowcmd. Answering a flood of them
took a core from the sim on a two-core machine (a 10 kHz sport-request flood: sim RTF 0.43). So:

- each take empties the reader as raw bytes (no decode): at most REQUEST_HISTORY wait in Cyclone's
  cache between takes, older ones are replaced there, uncounted;
- at most REQUESTS_PER_S a second (bursts of REQUEST_BURST) are decoded and answered, oldest first,
  the budget shared by both services;
- the rest are shed: counted (UnitreeStatus.requests_shed), logged at a bounded rate, not answered.
  An answer per shed request would make the adapter the flood's amplifier; the caller's client times
  out instead (the SDK's code 3104), as it would against a robot whose service is busy.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Final

from zensim.common.token_bucket import TokenBucket
from zensim.schemas import bounded

from .idl import Request_

REQUEST_HISTORY: Final = 32
"""Requests a service's reader keeps between two takes (Cyclone's default keeps 1)."""
REQUESTS_PER_S: Final = 100.0
"""Requests answered per second, sustained, over both services (LocoClient programs send a few; one
answer costs about a millisecond, so this is at most a tenth of a core)."""
REQUEST_BURST: Final = 50.0
"""Requests answered at once after a quiet spell."""


@dataclass
class Intake:
    """What one take of a service's requests gave: those to answer, those that did not decode, how many were shed."""

    requests: list[Request_] = field(default_factory=list)
    undecodable: list[str] = field(default_factory=list)
    """Why each undecodable sample was refused (bounded text); they count against the budget too."""
    shed: int = 0


class RequestBudget:
    """The answer budget both RPC services draw from (one per adapter)."""

    def __init__(self, rate_per_s: float = REQUESTS_PER_S, burst: float = REQUEST_BURST) -> None:
        self._bucket = TokenBucket(rate_per_s, burst)

    def admit(self, samples: list[bytes]) -> Intake:
        """Decode the samples the budget allows, oldest first; count the rest as shed.

        Args:
            samples: serialized Request_ samples (header included), oldest first.
        """
        intake = Intake()
        for data in samples:
            if not self._bucket.take():
                intake.shed += 1
                continue
            try:
                intake.requests.append(Request_.deserialize(data))
            except Exception as exc:  # the binding raises assorted errors on a sample it cannot decode
                intake.undecodable.append(bounded(f"{type(exc).__name__}: {exc}"))
        return intake
