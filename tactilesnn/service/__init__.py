"""Inference without torch: an onnxruntime session wrapper, an HTTP service and its client."""
