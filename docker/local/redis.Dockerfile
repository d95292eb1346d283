# Redis from the Debian archive on the local base, standing in for redis:7-alpine in the tests
# (docker/compose.test.yaml). Same contract: `redis-server` on PATH, data in /data.
ARG BASE_IMAGE=otgeo-base:bookworm
FROM ${BASE_IMAGE}
RUN apt-get update \
    && apt-get install -y --no-install-recommends redis-server redis-tools \
    && rm -rf /var/lib/apt/lists/* /var/cache/apt/archives/*.deb \
    && mkdir -p /data && chown redis:redis /data
USER redis
WORKDIR /data
VOLUME ["/data"]
EXPOSE 6379
CMD ["redis-server"]
