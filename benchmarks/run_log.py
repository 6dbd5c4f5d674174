"""A resumable log of benchmark runs: one JSON object per line, appended as each run finishes.

An interrupted study loses at most the runs in flight; run the command again and
the finished ones are skipped (the caller leaves them out of the jobs).
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from pathlib import Path

from joblib import Parallel, delayed
from tqdm import tqdm


def load_runs(path: Path) -> list[dict]:
    """Every run logged in ``path`` (empty if the file does not exist)."""
    return [json.loads(line) for line in path.read_text().splitlines()] if path.exists() else []


def append_runs(path: Path, run: Callable[..., dict], jobs: Sequence[tuple], workers: int) -> list[dict]:
    """``run(*job)`` for every job in ``workers`` processes, each result appended to ``path`` as it finishes.

    Parameters
    ----------
    path : Path
        The JSON-lines log.
    run : callable
        One run; returns a JSON-serialisable dict.
    jobs : sequence of tuple
        Positional arguments of each run.
    workers : int
        joblib processes.

    Returns
    -------
    list of dict
        The new runs, in the order they finished.
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    finished = []
    calls = (delayed(run)(*job) for job in jobs)
    with path.open("a") as out:
        for result in tqdm(Parallel(n_jobs=workers, return_as="generator_unordered")(calls), total=len(jobs),
                           unit="run"):
            out.write(json.dumps(result) + "\n")
            out.flush()
            finished.append(result)
    return finished


def run_missing(path: Path, run: Callable[..., dict], plants: Sequence[str], variants: Sequence[str], seeds: int,
                optima: dict[str, float], workers: int) -> list[dict]:
    """Every run logged in ``path``, plus those of ``plants x variants x seeds 0..seeds-1`` not logged yet.

    The missing runs are ``run(plant, variant, seed, optima[plant])``, appended to ``path``
    as they finish (see :func:`append_runs`); logged runs are identified by their
    ``plant``, ``variant`` and ``seed`` fields.
    """
    runs = load_runs(path)
    done = {(r["plant"], r["variant"], r["seed"]) for r in runs}
    todo = [(p, v, s, optima[p]) for p in plants for v in variants for s in range(seeds) if (p, v, s) not in done]
    return runs + append_runs(path, run, todo, workers)
