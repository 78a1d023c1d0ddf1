# racer: one image for every role (trainer, worker). Build: docker build -t racer .
FROM python:3.11-slim
# Mesa's EGL/GL let MuJoCo render headless (only camera="mujoco" needs it; the default camera does not).
RUN apt-get update && apt-get install -y --no-install-recommends libegl1 libgl1 libgomp1 \
    && rm -rf /var/lib/apt/lists/*
WORKDIR /app
# The CPU build of torch first: an unpinned torch would pull several GB of CUDA packages.
RUN pip install --no-cache-dir torch==2.13.0 --index-url https://download.pytorch.org/whl/cpu
COPY pyproject.toml README.md ./
COPY common common
COPY sim sim
COPY rollout_worker rollout_worker
COPY trainer trainer
COPY model_store model_store
COPY deploy deploy
COPY racer racer
RUN pip install --no-cache-dir .
ENV MUJOCO_GL=egl PYTHONUNBUFFERED=1
ENTRYPOINT ["racer"]
