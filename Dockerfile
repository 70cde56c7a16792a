# One image for every SkyNet Inspect service; the compose file picks the command.
FROM python:3.11-slim
# iproute2: `tc netem` for the latency/loss profile (needs NET_ADMIN at run time)
RUN apt-get update && apt-get install -y --no-install-recommends iproute2 && rm -rf /var/lib/apt/lists/*
WORKDIR /app
COPY pyproject.toml README.md ./
COPY protocol ./protocol
COPY edge ./edge
COPY services ./services
RUN pip install --no-cache-dir .
ENV PYTHONUNBUFFERED=1
ENTRYPOINT ["skynet"]
CMD ["--help"]
