# Stand-in for python:3.11-slim, built from a local Debian base where no image registry can be reached
# (deploy/cluster/check-compose.sh makes the base with debootstrap). Debian bookworm's Python is 3.11, like the
# official image's; a virtual environment first on PATH gives the same `python` and `pip` commands.
ARG BASE_IMAGE=racer-base:bookworm
FROM ${BASE_IMAGE}
RUN apt-get update \
    && apt-get install -y --no-install-recommends python3 python3-venv ca-certificates \
    && rm -rf /var/lib/apt/lists/* \
    && python3 -m venv /opt/python
# pip reads its CA bundle from certifi unless told: trust what the base trusts (the check script copies the host's
# extra CAs, e.g. a TLS-inspecting proxy's, into the base it makes).
ENV PATH=/opt/python/bin:$PATH LANG=C.UTF-8 PIP_CERT=/etc/ssl/certs/ca-certificates.crt
CMD ["python3"]
