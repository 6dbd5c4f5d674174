"""The path of the records through ``agents.twin.diagnose``: the modules their data visit, in order.

One diagnosis (:func:`agents.twin.workbench.diagnose`, one process) of one record set of
:mod:`benchmarks.bench_diagnose` (default: DCMotor-v0 with a hidden saturation) runs under
:func:`sys.setprofile`. A frame of a module of ``agents.twin`` *holds the data* when, at its call
(its arguments) or at its return (all its locals), one of its local variables is a record form:
an :class:`~gbo_envs.Experiment`, a stacked batch of records (any class of ``agents.twin`` whose name
is ``Batch`` or ``GreyData``), a ``{"t", "r", "u", "y"}`` mapping, or a list or tuple of those.
Each function counts once, at its first frame that holds the data (the path through the code, not
the iterations of its loops; ``--every-frame`` counts every frame). The functions that hold the data, in
the order they are entered, give the sequence of their modules:

* a **stay** is a run of consecutive such frames in one module (they merge into one stay);
* a **return** is a stay in a module that an earlier stay already left.

The methods of a record form itself (a frame whose ``self`` is one, and no other local) are the data's
own behaviour, not a stage it is handed to: they are counted apart (``with_methods``).

A pipeline that reads top-down visits each module once: as many stays as modules, no returns.
Prints one JSON object: the case, the stays, the distinct modules, the returns, the stays'
modules in order (``path``) and the seconds the traced diagnosis took::

    python benchmarks/data_path.py
    python benchmarks/data_path.py --case dcmotor_backlash --experiments 6 --path
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Mapping
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
if str(REPO / "benchmarks") not in sys.path:  # bench_diagnose is a script of this folder
    sys.path.insert(0, str(REPO / "benchmarks"))

from bench_diagnose import CASES, case_records  # noqa: E402

from gbo_envs.experiment import Experiment  # noqa: E402

#: The names of the classes of ``agents.twin`` that stack records.
BATCH_NAMES = frozenset({"Batch", "GreyData"})
#: The package whose modules are followed.
PACKAGE = "agents.twin"


def is_record_form(value) -> bool:
    """Whether ``value`` is one of the forms records take: an Experiment, a batch, a signal mapping, or a
    list or tuple whose first item is one of those."""
    if isinstance(value, (list, tuple)) and value:
        value = value[0]
    if isinstance(value, Experiment):
        return True
    kind = type(value)
    if kind.__name__ in BATCH_NAMES and kind.__module__.startswith(PACKAGE):
        return True
    return isinstance(value, Mapping) and {"t", "r", "u", "y"} <= set(value)


class DataPath:
    """A profile function recording the modules of ``agents.twin`` whose frames hold record data."""

    def __init__(self, every_frame: bool = False) -> None:
        self.every_frame = every_frame
        self._seen: set = set()  # the code objects that held data already
        self._entered: dict[int, int] = {}  # id(frame) -> position of its call among the package's calls
        self._held: list[tuple[int, str]] = []
        self._calls = 0

    def __call__(self, frame, event: str, arg) -> None:
        if event not in ("call", "return"):
            return
        module = frame.f_globals.get("__name__", "")
        if not module.startswith(PACKAGE):
            return
        key = id(frame)
        if not self.every_frame and frame.f_code in self._seen:
            return
        if event == "call":
            self._calls += 1
            self._entered[key] = self._calls
            if any(is_record_form(v) for v in frame.f_locals.values()):
                self._hold(self._calls, module, frame)
                self._entered[key] = -1  # counted already
            return
        position = self._entered.pop(key, None)
        if position is not None and position >= 0 and any(is_record_form(v) for v in frame.f_locals.values()):
            self._hold(position, module, frame)

    def _hold(self, position: int, module: str, frame) -> None:
        local = frame.f_locals
        method = is_record_form(local.get("self")) and not any(
            is_record_form(v) for k, v in local.items() if k != "self")
        self._held.append((position, module, method))
        self._seen.add(frame.f_code)

    def stays(self, with_methods: bool = False) -> list[str]:
        """The module of each stay, in order (``with_methods``: the record forms' own methods counted too)."""
        out: list[str] = []
        for _, module, method in sorted(self._held):
            if method and not with_methods:
                continue
            if not out or out[-1] != module:
                out.append(module)
        return out


def measure(case: str = "dcmotor_saturation", n_experiments: int = 12, seed: int = 0,
            every_frame: bool = False) -> dict:
    """Trace one diagnosis of ``case``; the stays, modules and returns of its data (``every_frame``: each frame
    counted, not each function once)."""
    from agents.twin.workbench import diagnose
    from gbo_envs.physics.kernels import warm_up

    records = case_records(case, n_experiments, seed)[0]
    warm_up()
    tracer = DataPath(every_frame)
    start = time.perf_counter()
    sys.setprofile(tracer)
    try:
        data = _as_data(records)
        diagnose(data, n_jobs=1)
    finally:
        sys.setprofile(None)
    seconds = time.perf_counter() - start
    out = {"benchmark": "data_path", "case": case, "n_experiments": n_experiments, "every_frame": every_frame,
           "seconds": round(seconds, 1)}
    for label, with_methods in (("", False), ("with_methods_", True)):
        path = tracer.stays(with_methods)
        out.update({f"{label}stays": len(path), f"{label}modules": len(set(path)),
                    f"{label}returns": sum(1 for i, module in enumerate(path) if module in path[:i]),
                    f"{label}path": [module.removeprefix(PACKAGE + ".") for module in path]})
    return out


def _as_data(records):
    """The records as the diagnosis takes them (the batch the CLI makes of a CSV's experiments)."""
    try:
        from agents.twin.records import Batch

        if hasattr(Batch, "from_records"):
            return Batch.from_records(records)
    except ImportError:
        pass
    from agents.twin.data import GreyData  # the stacked records' class before there was one batch type

    return GreyData.from_records(records)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--case", choices=list(CASES), default="dcmotor_saturation")
    parser.add_argument("--experiments", type=int, default=12)
    parser.add_argument("--path", action="store_true", help="also print the stays' modules in order")
    parser.add_argument("--every-frame", action="store_true", help="count every frame, not each function once")
    args = parser.parse_args()
    result = measure(args.case, args.experiments, every_frame=args.every_frame)
    if not args.path:
        result.pop("path")
        result.pop("with_methods_path")
    print(json.dumps(result))
