# Stand-in for minio/minio and minio/mc where no image registry can be reached: moto's S3 server (from PyPI) on
# the Python stand-in. `standin-s3 server DIR ...` takes MinIO's command line and keeps the objects in DIR (the
# minio-data volume), so that they outlive the container as MinIO's do; `mc` is a stand-in for the few mc commands
# docker-compose.yml runs (mc ready, mc alias set, mc mb), all aimed at $STANDIN_S3_ADDRESS. No credential checks.
ARG PYTHON_IMAGE=racer-standin-python:test
FROM ${PYTHON_IMAGE}
RUN pip install --no-cache-dir "moto[server]>=5.1,<6"
COPY standin_s3.py /usr/local/bin/standin-s3
RUN ln -s standin-s3 /usr/local/bin/mc
ENTRYPOINT ["standin-s3"]
CMD ["server", "/data"]
