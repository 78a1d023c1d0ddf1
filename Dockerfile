# racer: one image for every role (trainer, worker, evaluator) and every other racer command.
#   docker build -t racer .
# Build arguments; their defaults are what a machine that reaches Docker Hub and download.pytorch.org wants:
#   BASE_IMAGE       a Debian-based image with Python >= 3.11 and `pip` on PATH          (python:3.11-slim)
#   TORCH_SPEC       the torch requirement                                                 (torch==2.13.0)
#   TORCH_INDEX_URL  the index torch comes from: PyTorch's CPU wheels, a mirror of them,   (https://download.pytorch.org/whl/cpu)
#                    or any PEP 503 folder that holds the wheel (deploy/cluster/check-compose.sh serves a local wheel)
# e.g. docker build --build-arg BASE_IMAGE=registry.example.com/python:3.11-slim \
#        --build-arg TORCH_INDEX_URL=https://mirror.example.com/pytorch/whl/cpu -t racer .
# The other packages come from pip's default index (PyPI); pass PIP_INDEX_URL as a build argument to change it.
ARG BASE_IMAGE=python:3.11-slim
FROM ${BASE_IMAGE}
ARG TORCH_SPEC=torch==2.13.0
ARG TORCH_INDEX_URL=https://download.pytorch.org/whl/cpu
ARG PIP_INDEX_URL
# Mesa's EGL/GL let MuJoCo render headless (only camera="mujoco" needs it; the default camera does not).
RUN apt-get update && apt-get install -y --no-install-recommends libegl1 libgl1 libgomp1 \
    && rm -rf /var/lib/apt/lists/*
WORKDIR /app
# The CPU build of torch first, alone (an unpinned torch would pull several GB of CUDA packages); its own small
# dependencies (filelock, sympy, ...) come from the default index with racer's below, and `pip check` proves it.
RUN pip install --no-cache-dir --no-deps "${TORCH_SPEC}" --index-url "${TORCH_INDEX_URL}"
# racer's dependencies next, from the project's metadata alone, so that editing the sources keeps this layer.
COPY pyproject.toml README.md ./
RUN pip install --no-cache-dir . && pip uninstall -y -q racer
COPY common common
COPY sim sim
COPY rollout_worker rollout_worker
COPY trainer trainer
COPY model_store model_store
COPY deploy deploy
COPY racer racer
RUN pip install --no-cache-dir --no-deps . && pip check && rm -rf build ./*.egg-info \
    && useradd --create-home --uid 10001 racer
# Roles run unprivileged; the trainer writes TensorBoard files (and racer train its logs) under the working folder.
USER racer
WORKDIR /home/racer
ENV MUJOCO_GL=egl PYTHONUNBUFFERED=1
ENTRYPOINT ["racer"]
