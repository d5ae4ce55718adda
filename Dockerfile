# zensim: one image for every service (router, sim, bridge, viz).
#
#   docker build -t zensim:latest .                                       # official python:3.11-slim
#   docker build --build-arg BASE_IMAGE=zensim-base:bookworm -t zensim:latest .   # offline base, see
#                                                                          # scripts/build-base-image
# Works with the classic builder and with BuildKit (no `# syntax=` line, no RUN --mount: nothing to pull).
#
# Build args:
#   BASE_IMAGE       any Debian-like image with python3 >= 3.11 and the venv module
#   EXTRA_CA_CERTS   PEM text of extra CA certificates that pip must trust during the build (for a
#                    TLS-intercepting proxy); used only in the `deps` stage, so it does not appear in the
#                    final image nor its history. Example:
#                      --build-arg EXTRA_CA_CERTS="$(cat /usr/local/share/ca-certificates/*.crt)"
#   PIP_INDEX_URL    a PyPI mirror (optional; pip reads it from the environment)
#   UNITREE          1: also install Cyclone DDS 0.10.2 (Debian's cyclonedds-dev and the Python binding
#                    built against it, scripts/install-cyclonedds) for `zensim unitree`; default 0
#   ROS1             1: also install Debian's ROS 1 (roscore, rospy and the message packages) for
#                    `zensim ros1` and a `roscore` container (compose profile `ros1`); default 0
#
# Layers of the final image: base | user | venv with the dependencies (changes only when
# pyproject.toml changes) | the project itself (small; changes with the source).
ARG BASE_IMAGE=python:3.11-slim

# ---------------------------------------------------------------------------------------------
# deps: a venv with the runtime dependencies listed in pyproject.toml (and nothing of the source)
FROM ${BASE_IMAGE} AS deps
ARG EXTRA_CA_CERTS=""
ARG PIP_INDEX_URL
ENV PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    PIP_ROOT_USER_ACTION=ignore \
    PIP_DEFAULT_TIMEOUT=120
# The build backend (setuptools) goes to /opt/buildtools, outside the runtime venv.
# A venv, not the system interpreter: Debian's python3 is "externally managed" (PEP 668), the
# official image's is not; a venv behaves the same on both.
RUN python3 -m venv /opt/venv
COPY pyproject.toml /src/pyproject.toml
RUN set -eu; \
    if [ -n "$EXTRA_CA_CERTS" ]; then \
        bundle=$(/opt/venv/bin/python -c 'import pip._vendor.certifi as c; print(c.where())'); \
        { cat "$bundle"; printf '\n%s\n' "$EXTRA_CA_CERTS"; } > /tmp/ca-bundle.pem; \
        export PIP_CERT=/tmp/ca-bundle.pem; \
    fi; \
    /opt/venv/bin/python -c 'import tomllib; print("\n".join(tomllib.load(open("/src/pyproject.toml", "rb"))["project"]["dependencies"]))' \
        > /tmp/requirements.txt; \
    /opt/venv/bin/pip install -r /tmp/requirements.txt; \
    build_requires=$(/opt/venv/bin/python -c 'import tomllib; print(" ".join(tomllib.load(open("/src/pyproject.toml", "rb"))["build-system"]["requires"]))'); \
    /opt/venv/bin/pip install --target /opt/buildtools $build_requires wheel; \
    rm -f /tmp/ca-bundle.pem /tmp/requirements.txt
# Optional: Cyclone DDS for `zensim unitree` (the compose profile `unitree`), the same way
# scripts/install-system-deps + scripts/install-cyclonedds install it on a host. A separate layer, so
# the layer above stays cached. The runtime stage installs just the C library it names.
ARG UNITREE=0
COPY scripts/install-cyclonedds /src/scripts/install-cyclonedds
RUN set -eu; \
    if [ "$UNITREE" = 1 ]; then \
        export DEBIAN_FRONTEND=noninteractive; \
        apt-get update -qq; \
        headers=$(/opt/venv/bin/python -c 'import os, sysconfig; print("" if os.path.exists(os.path.join(sysconfig.get_paths()["include"], "Python.h")) else "python3-dev")'); \
        apt-get install -y -qq --no-install-recommends cyclonedds-dev gcc libc6-dev $headers >/dev/null; \
        if [ -n "$EXTRA_CA_CERTS" ]; then \
            bundle=$(/opt/venv/bin/python -c 'import pip._vendor.certifi as c; print(c.where())'); \
            { cat "$bundle"; printf '\n%s\n' "$EXTRA_CA_CERTS"; } > /tmp/ca-bundle.pem; \
            export PIP_CERT=/tmp/ca-bundle.pem; \
        fi; \
        /src/scripts/install-cyclonedds /opt/venv/bin/python; \
        apt-cache depends cyclonedds-dev | awk '/Depends: libddsc/ {print $2}' > /opt/venv/unitree-runtime-packages; \
        rm -f /tmp/ca-bundle.pem; \
    fi

# ---------------------------------------------------------------------------------------------
# app: install the project itself (no dependencies, no network) and stage just its files
FROM deps AS app
COPY . /src
# then copy only the files pip installed for zensim (package dirs, dist-info, bin/zensim) to /stage
RUN set -eu; \
    PYTHONPATH=/opt/buildtools /opt/venv/bin/pip install --no-index --no-deps --no-build-isolation /src; \
    /opt/venv/bin/python -c 'if 1: \
        import importlib.metadata as md, pathlib, shutil; \
        dist = md.distribution("zensim"); \
        files = [pathlib.Path(dist.locate_file(f)).resolve() for f in dist.files]; \
        [(pathlib.Path("/stage", f.relative_to("/")).parent.mkdir(parents=True, exist_ok=True), \
          shutil.copy2(f, pathlib.Path("/stage", f.relative_to("/")))) for f in files if f.is_file()]'

# ---------------------------------------------------------------------------------------------
# runtime
FROM ${BASE_IMAGE} AS runtime
# Fixed uid/gid so that bind mounts can be chowned predictably.
# --no-log-init: a high uid would otherwise grow a sparse /var/log/lastlog of ~GBs in the layer.
RUN groupadd --gid 10001 zensim \
 && useradd --uid 10001 --gid 10001 --no-log-init --create-home --home-dir /home/zensim \
            --shell /usr/sbin/nologin zensim
ENV VIRTUAL_ENV=/opt/venv \
    PATH=/opt/venv/bin:$PATH \
    PYTHONUNBUFFERED=1 \
    PYTHONDONTWRITEBYTECODE=1
# Debian's ROS 1 for `zensim ros1` (build arg ROS1=1): rospy lives in /usr/lib/python3/dist-packages,
# where the gateway finds it from the venv (docs/ros.md); ros-base brings roscore for the compose profile.
# Before the venv: this layer stays cached while the dependencies change.
ARG ROS1=0
RUN set -eu; \
    if [ "$ROS1" = 1 ]; then \
        export DEBIAN_FRONTEND=noninteractive; \
        apt-get update -qq; \
        apt-get install -y -qq --no-install-recommends ros-base python3-rospy python3-std-msgs \
            python3-sensor-msgs python3-nav-msgs python3-geometry-msgs python3-rosgraph-msgs python3-tf2-msgs \
            >/dev/null; \
        rm -rf /var/lib/apt/lists/*; \
    fi
COPY --from=deps /opt/venv /opt/venv
# The Cyclone DDS C library when the venv holds the binding (build arg UNITREE=1).
RUN set -eu; \
    if [ -s /opt/venv/unitree-runtime-packages ]; then \
        export DEBIAN_FRONTEND=noninteractive; \
        apt-get update -qq; \
        apt-get install -y -qq --no-install-recommends $(cat /opt/venv/unitree-runtime-packages) >/dev/null; \
        rm -rf /var/lib/apt/lists/*; \
    fi
COPY --from=app /stage/ /
USER zensim
WORKDIR /home/zensim
# 7447: Zenoh (router), 7000: viz web page (the ros1 profile runs on the host network)
EXPOSE 7447 7000
ENTRYPOINT ["zensim"]
CMD ["--help"]
