"""Application layer: what a user asks for, as typed objects executed by one function each
(run folders, data-file defaults and encoder selection, sweeps, benchmarks)."""
