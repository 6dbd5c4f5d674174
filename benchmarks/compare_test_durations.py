"""The same tests in two trees: compare two ``pytest --durations=0`` logs (issue 37's "make test no slower").

The suite grows, so its total time mixes a change's effect with the tests added since. This
sums each test's setup, call and teardown seconds (pytest's ``--durations=0`` lines; pytest hides
those under 5 ms) over the tests that both logs time, and reports the tests only one log has apart::

    cd OLD_TREE && python -m pytest -n 2 -p no:cacheprovider --durations=0 > old.log
    cd NEW_TREE && python -m pytest -n 2 -p no:cacheprovider --durations=0 > new.log
    python benchmarks/compare_test_durations.py old.log new.log

Seconds are worker seconds (with ``-n 2`` two workers run at once), not wall time.
"""

from __future__ import annotations

import argparse
import re
from collections import Counter
from pathlib import Path

_DURATION = re.compile(r"^([\d.]+)s (?:setup|call|teardown)\s+(\S.*)$")
_SUMMARY = re.compile(r"(\d+) passed.* in ([\d.]+)s")


def read_durations(path: Path) -> tuple[Counter, str | None]:
    """``{test id: seconds}`` summed over its phases, and the log's summary line (``N passed ... in S s``)."""
    seconds, summary = Counter(), None
    for line in path.read_text(errors="replace").splitlines():
        if match := _DURATION.match(line.strip()):
            seconds[match.group(2)] += float(match.group(1))
        elif _SUMMARY.search(line):
            summary = line.strip(" =")
    return seconds, summary


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("old", type=Path, help="pytest --durations=0 log of the old tree")
    parser.add_argument("new", type=Path, help="pytest --durations=0 log of the new tree")
    parser.add_argument("--top", type=int, default=5, help="tests with the largest changes to list (default 5)")
    args = parser.parse_args()
    old, old_summary = read_durations(args.old)
    new, new_summary = read_durations(args.new)
    if not old or not new:
        parser.error("no --durations lines found: run pytest with --durations=0")
    common = set(old) & set(new)
    before, after = sum(old[t] for t in common), sum(new[t] for t in common)
    print(f"old: {old_summary}\nnew: {new_summary}")
    only_old, only_new = len(set(old) - common), len(set(new) - common)
    print(f"tests timed in both: {len(common)} (only old: {only_old}, only new: {only_new})")
    print(f"their worker seconds: {before:.1f} -> {after:.1f} ({100.0 * (after / before - 1.0):+.1f} %)")
    print(f"tests only in new: {sum(new[t] for t in set(new) - common):.1f} s")
    changes = sorted(common, key=lambda t: new[t] - old[t])
    for label, tests in (("largest gains", changes[: args.top]), ("largest losses", changes[::-1][: args.top])):
        print(f"{label}:")
        for test in tests:
            print(f"  {old[test]:7.2f} -> {new[test]:7.2f} s  {test}")


if __name__ == "__main__":
    main()
