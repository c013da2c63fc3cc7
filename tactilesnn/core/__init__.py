"""The bottom layer: what every other part of tactilesnn shares and nothing here imports from
above it.

- :mod:`.checks` input checks with specific errors; :mod:`.spikes` the one spike format
  (times in ms, ``+inf`` = silent) and its rasters; :mod:`.registry` the component registries;
- :mod:`.data` the data contract (:class:`~.data.WindowDataset`);
- :mod:`.graph_contract` the exported graph's I/O names and metadata as one typed object, written
  by the export and read by the service; :mod:`.onnx_run` batched onnxruntime calls;
- :mod:`.onnx_graph`, :mod:`.onnx_shapes`, :mod:`.onnx_prune` ONNX graph building and passes;
- :mod:`.perf` threads and allocator; :mod:`.dask_run` running jobs on a Dask cluster;
  :mod:`.version` the package version.
"""
