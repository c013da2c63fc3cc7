"""Export of trained pipelines: ONNX (:mod:`.onnx`) and NIR (:mod:`.nir`)."""

from .onnx import data_hash, export_pipeline, quantize_int8, verify

__all__ = ["data_hash", "export_pipeline", "quantize_int8", "verify"]
