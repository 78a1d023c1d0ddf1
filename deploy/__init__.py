"""racer.deploy: a trained policy on a car, without PyTorch at run time.

``export`` writes a checkpoint as ONNX with model_metadata.json beside it (``racer export``); ``model_file``
reads and stamps the model's ``racer`` metadata; ``runtime`` runs camera frames through the ONNX policy on one
CPU thread (``racer car``); ``vehicle`` maps actions to servo and ESC outputs. ``cluster`` is apart: the test
harness that runs racer's roles across containers and network links (not in the wheel). See ARCHITECTURE.md.
"""
