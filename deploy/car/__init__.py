"""What runs on the car: the exported model's file format (``model_file``), the camera-to-action loop
(``runtime``) and the servo calibration (``vehicle``). Needs onnxruntime and OpenCV, never PyTorch."""
