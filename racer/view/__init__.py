"""``racer view``: a run followed live in the browser (docs/view.md).

``server`` finds the run's store and Redis and serves the page with uvicorn; ``app`` is the Starlette app (page,
JSON endpoints, camera stream, access check); ``data`` reads the store; ``live`` reads Redis for every page at once.
The workers' side is ``rollout_worker/watch.py``.
"""
