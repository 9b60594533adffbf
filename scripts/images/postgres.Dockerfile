# PostgreSQL from Debian's postgresql package, in place of the official postgres image where no
# image registry is reachable (scripts/docker-images.sh). As the official image: POSTGRES_USER
# (superuser, default postgres), POSTGRES_PASSWORD, POSTGRES_DB (default: the user's name) and
# POSTGRES_HOST_AUTH_METHOD (default scram-sha-256) on the first start with an empty data
# folder; data in the volume /var/lib/postgresql/data (PGDATA); the server runs as postgres and
# listens on every interface of the container; pg_isready and psql on PATH.
ARG BASE_IMAGE=cmrt-base:bookworm
FROM ${BASE_IMAGE}
ENV DEBIAN_FRONTEND=noninteractive
# Debian's package would create and start a cluster of its own: the data folder is ours.
RUN mkdir -p /etc/postgresql-common/createcluster.d \
 && echo "create_main_cluster = false" > /etc/postgresql-common/createcluster.d/no-main.conf \
 && apt-get update \
 && apt-get install -y --no-install-recommends postgresql \
 && rm -rf /var/lib/apt/lists/* \
 && ln -s /usr/lib/postgresql/*/bin /usr/lib/postgresql/bin \
 && mkdir -p /var/run/postgresql /var/lib/postgresql/data \
 && chown -R postgres:postgres /var/run/postgresql /var/lib/postgresql \
 && chmod 2777 /var/run/postgresql
ENV PATH=/usr/lib/postgresql/bin:$PATH PGDATA=/var/lib/postgresql/data
COPY postgres-entrypoint.sh /usr/local/bin/docker-entrypoint.sh
VOLUME /var/lib/postgresql/data
EXPOSE 5432
STOPSIGNAL SIGINT
ENTRYPOINT ["/usr/local/bin/docker-entrypoint.sh"]
CMD ["postgres"]
