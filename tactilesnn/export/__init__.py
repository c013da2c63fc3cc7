"""Export of trained pipelines: ONNX (:mod:`.onnx`) and NIR (:mod:`.nir`)."""

from .onnx import ExportError, data_hash, export_pipeline, quantize_int8, verify

__all__ = ["ExportError", "data_hash", "export_pipeline", "quantize_int8", "verify"]
