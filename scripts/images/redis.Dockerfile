# Redis from Debian's redis-server, in place of the official redis image where no image registry
# is reachable (scripts/docker-images.sh). As the official image: data in the volume /data,
# `redis-server ARGS` as the command, run as the redis user, protected mode off (the compose
# network is the boundary), port 6379; redis-cli for the health check.
ARG BASE_IMAGE=cmrt-base:bookworm
FROM ${BASE_IMAGE}
ENV DEBIAN_FRONTEND=noninteractive
RUN apt-get update \
 && apt-get install -y --no-install-recommends redis-server redis-tools \
 && rm -rf /var/lib/apt/lists/* \
 && mkdir -p /data && chown redis:redis /data
COPY redis-entrypoint.sh /usr/local/bin/docker-entrypoint.sh
VOLUME /data
WORKDIR /data
EXPOSE 6379
ENTRYPOINT ["/usr/local/bin/docker-entrypoint.sh"]
CMD ["redis-server"]
