"""The docs that describe settings stay true: each service README holds its generated settings table."""

from __future__ import annotations

import pytest

from support import REPO
from zensim.common.settings import settings_table
from zensim.router import RouterSettings
from zensim.bridge.settings import BridgeSettings
from zensim.loco.settings import LocoSettings
from zensim.sim.settings import SimSettings
from zensim.ros1.settings import Ros1Settings
from zensim.ros2.settings import Ros2Settings
from zensim.unitree.settings import UnitreeSettings
from zensim.viz.settings import VizSettings
from zensim.scenario import ScenarioSettings
from zensim.course import CourseSettings


@pytest.mark.parametrize(
    "readme, settings", [("services/sim/README.md", SimSettings), ("services/bridge/README.md", BridgeSettings),
     ("services/viz/README.md", VizSettings), ("docs/deployment.md", RouterSettings),
     ("services/unitree/README.md", UnitreeSettings), ("services/ros1/README.md", Ros1Settings),
     ("services/ros2/README.md", Ros2Settings),
     ("services/loco/README.md", LocoSettings),
     ("docs/bench.md", ScenarioSettings), ("docs/bench.md", CourseSettings)]
)
def test_service_readme_lists_every_setting(readme: str, settings: type) -> None:
    """Paste `settings_table(...)` output into the README when this fails."""
    assert settings_table(settings) in (REPO / readme).read_text()
