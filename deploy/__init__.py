"""racer.deploy: a trained policy to where users race it.

Exporters (on the training machine, with PyTorch): ``export`` writes a checkpoint as ONNX with model_metadata.json
beside it (``racer export``); ``deepracer_graph``, ``deepracer_format`` and ``importer`` write and read DeepRacer's
own model formats (``racer export --format deepracer-car|deepracer-sim``, ``racer import``; TensorFlow, the
``deepracer`` extra). ``car`` is what runs on the car without PyTorch: the model file, the camera-to-action loop and
the servo calibration. ``cluster`` is apart: the test harness that runs racer's roles across containers and network
links (not in the wheel). See ARCHITECTURE.md.
"""
