# One image for every SkyNet Inspect service; the compose file picks the command.
#
# Any base with Python 3.11+ and its venv module works: the official image by default, or your
# own (a private mirror, or the local Debian base scripts/docker-base.sh makes on a machine without
# Docker Hub):  docker compose build --build-arg BASE_IMAGE=skynet-local/python:3.11-bookworm
# Everything installs into a venv (/opt/skynet), so a Debian python3 base (PEP 668,
# "externally-managed-environment") works as well as python:3.11-slim.
ARG BASE_IMAGE=python:3.11-slim
FROM ${BASE_IMAGE}

ENV VIRTUAL_ENV=/opt/skynet \
    PATH=/opt/skynet/bin:$PATH \
    PYTHONUNBUFFERED=1 \
    PYTHONDONTWRITEBYTECODE=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    PIP_NO_CACHE_DIR=1 \
    MPLCONFIGDIR=/opt/skynet/mplconfig \
    RUST_LOG=error

# iproute2 (tc) only for the optional kernel-netem profile; skipped when the base already has it
RUN command -v tc >/dev/null 2>&1 || { apt-get update && apt-get install -y --no-install-recommends iproute2 \
      && rm -rf /var/lib/apt/lists/*; }

# Dependencies first, in a layer of their own: a code change does not reinstall them. Every extra a
# service may need (mavlink: the real-autopilot driver); not the test and bench extras.
ARG EXTRAS=mavlink
COPY pyproject.toml /tmp/skynet/pyproject.toml
RUN python3 -m venv "$VIRTUAL_ENV" \
 && python -c 'import sys, tomllib; d = tomllib.load(open(sys.argv[1], "rb")); p = d["project"]; \
print(*p["dependencies"], *d["build-system"]["requires"], \
      *(r for e in sys.argv[2].split(",") if e for r in p["optional-dependencies"][e]), sep="\n")' \
      /tmp/skynet/pyproject.toml "$EXTRAS" > /tmp/skynet/requirements.txt \
 && pip install -r /tmp/skynet/requirements.txt \
 && mkdir -p "$MPLCONFIGDIR" && python -c 'import matplotlib.pyplot' && chmod -R a+rX "$MPLCONFIGDIR"

# The code, installed without touching the dependencies (and without a build-isolation download).
WORKDIR /opt/skynet/src
COPY pyproject.toml README.md ./
COPY protocol ./protocol
COPY edge ./edge
COPY services ./services
RUN pip install --no-deps --no-build-isolation . && rm -rf build *.egg-info \
 && skynet --help >/dev/null

WORKDIR /work
ENTRYPOINT ["skynet"]
CMD ["--help"]
