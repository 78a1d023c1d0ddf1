# Stand-in for redis:7-alpine where no image registry can be reached: Debian bookworm's redis-server (7.0) on the
# local base. It runs the command docker-compose.yml gives (redis-server ... --requirepass ...) and its health check
# (redis-cli ping) unchanged; with $STANDIN_REDIS_PORT set (the test override runs it on the host's network) both
# use 127.0.0.1 at that port.
ARG BASE_IMAGE=racer-base:bookworm
FROM ${BASE_IMAGE}
RUN apt-get update \
    && apt-get install -y --no-install-recommends redis-server \
    && rm -rf /var/lib/apt/lists/*
COPY standin-redis redis-cli /usr/local/bin/
USER redis
WORKDIR /var/lib/redis
ENTRYPOINT ["standin-redis"]
CMD ["redis-server"]
