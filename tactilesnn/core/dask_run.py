"""Running independent calls on a Dask cluster (the optional ``distributed`` extra)."""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence


def on_dask(
    fn: Callable, calls: Sequence[tuple], scheduler: str, retries: int = 2
) -> Iterator[tuple[int, object]]:
    """``fn(*args)`` for every ``args`` of ``calls`` on the cluster at ``scheduler``, yielding
    ``(index into calls, result)`` as each finishes. A call whose worker dies is run again
    elsewhere (up to ``retries`` times), so ``fn`` must be idempotent."""
    try:
        from distributed import Client, as_completed
    except ImportError as e:
        raise ValueError(
            "--scheduler needs Dask distributed: pip install -c constraints.txt -e '.[distributed]'"
        ) from e
    with Client(scheduler, timeout="20s") as client:
        futs = {client.submit(fn, *args, pure=False, retries=retries): i
                for i, args in enumerate(calls)}  # fmt: skip
        for f in as_completed(futs):
            yield futs[f], f.result()
