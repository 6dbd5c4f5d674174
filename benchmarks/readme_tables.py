"""Render the tables of ``benchmarks/README.md`` that come from the committed JSON results.

Each table sits between two marker comments, ``<!-- NAME -->`` and ``<!-- /NAME -->``, and is
rendered from ``benchmarks/results/`` by the function :data:`SECTIONS` names for it: the cost
surfaces of ``rig_surfaces.py`` (``rig_surfaces.json``), the optimum's move against the number of
noise draws (``rig_draws_sweep.json``) and the rigs' shipped ground-truth tables of
``ground_truth_tables.py`` (``ground_truth_tables.json``: grids, and the certified searches of envs
with more than two gains). Everything outside the markers is
left as it is. ``tests/test_readme.py`` checks that the committed tables are what this script
renders from the committed results.

Usage, from the repository root::

    python benchmarks/readme_tables.py            # rewrite the tables in benchmarks/README.md
    python benchmarks/readme_tables.py --check    # exit 1 if they differ from the results
"""

from __future__ import annotations

import argparse
import json
import re
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README = Path("benchmarks") / "README.md"
RESULTS = Path("benchmarks") / "results"


def _load(root: Path, name: str):
    return json.loads((root / RESULTS / name).read_text())


def _env(name: str) -> str:
    return name.removeprefix("gbo_envs/")


def _gains(values: list[float]) -> str:
    return "(" + ", ".join(f"{value:.4g}" for value in values) + ")"


def _table(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return "\n".join(lines)


def rig_surfaces(root: Path) -> str:
    """Every env's ground-truth surface: ``J*``, its gains, the near-optimal shares, the noise."""
    rows = []
    for entry in _load(root, "rig_surfaces.json"):
        noise = "-"
        if entry.get("stochastic"):
            cells = entry["optimum_move_cells"]
            noise = (f"{entry['expectation_draws']} draws: optimum moves {cells} cell{'s' * (cells != 1)}, "
                     f"J* s.e. {entry['standard_error_pct']:.3f} %")
        shares = " / ".join(f"{100 * entry[f'share_{ratio}']:.2f}" for ratio in ("1.01", "1.05", "1.1"))
        rows.append([f"`{_env(entry['env'])}`", f"{entry['J*']:.4f}", _gains(entry["optimum"]), shares,
                     f"{entry['regions_1.1']}", f"{entry['median_ratio']:.2f}", f"{entry['ground_truth_s']:.2f}",
                     noise])
    return _table(["env", "J*", "optimum (gains)", "% of box within 1.01 / 1.05 / 1.1 J*", "regions within 1.1",
                   "median J / J*", "ground truth s", "noise of J*"], rows)


def rig_draws_sweep(root: Path) -> str:
    """The optimum's move between two independent sets of noise draws, against their number."""
    rows = []
    for env, sweep in _load(root, "rig_draws_sweep.json").items():
        for entry in sweep:
            rows.append([f"`{_env(env)}`", f"{entry['expectation_draws']}", f"{entry['optimum_move_cells']}",
                         " / ".join(f"{value:.5f}" for value in entry["J*"]), f"{entry['cpu_s']:.1f}"])
    return _table(["env", "draws K", "optimum move (cells)", "J* of the two draw sets", "CPU s"], rows)


def ground_truth_tables(root: Path) -> str:
    """The shipped ground truths: a 100 x 100 grid (two gains) or a certified search (more gains).

    A search's optimum is certified when a second, independent search ends within its tolerance
    (relative difference of ``J*``).
    """
    rows = []
    for entry in _load(root, "ground_truth_tables.json"):
        if "search" in entry:
            search = entry["search"]
            method = (f"search: {search['n_points']} Sobol points, {search['n_starts']} starts; second search "
                      f"within {entry['disagreement']:.1e} ({'certified' if entry['certified'] else 'not certified'}"
                      f" at {entry['tolerance']:g})")
            optimum = _gains(list(entry["gains"].values()))
        else:
            method = f"grid {entry['resolution']} x {entry['resolution']}"
            optimum = f"cell {_gains(entry['optimum_cell'])}"
        rows.append([f"`{_env(entry['env'])}`", method, f"{entry['expectation_draws']}", f"{entry['J*']:.5f}",
                     optimum, f"{entry['cpu_s_this_run']:.1f}", f"{entry['table_bytes'] / 1000:.1f} kB"])
    return _table(["env", "method", "draws", "J*", "optimum", "CPU s of the last run", "table"], rows)


#: the generated tables: marker name -> renderer of its Markdown from the repository root
SECTIONS: dict[str, Callable[[Path], str]] = {
    "rig_surfaces": rig_surfaces,
    "rig_draws_sweep": rig_draws_sweep,
    "ground_truth_tables": ground_truth_tables,
}


def render(text: str, root: Path = ROOT) -> str:
    """``text`` with every table between its markers rendered anew from ``root``'s results.

    Raises
    ------
    ValueError
        If a marker pair of :data:`SECTIONS` is missing from ``text``.
    """
    for name, renderer in SECTIONS.items():
        pattern = re.compile(rf"(<!-- {name} -->\n)(.*?)(<!-- /{name} -->)", re.S)
        if not pattern.search(text):
            raise ValueError(f"text: no <!-- {name} --> ... <!-- /{name} --> markers")
        text = pattern.sub(lambda match, r=renderer: match.group(1) + r(root) + "\n" + match.group(3), text)
    return text


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="exit 1 if the README's tables differ from the results")
    args = parser.parse_args(argv)
    path = ROOT / README
    text = path.read_text()
    rendered = render(text)
    if args.check:
        if rendered != text:
            print(f"{README}: the generated tables differ from {RESULTS}; run python benchmarks/readme_tables.py")
            return 1
        return 0
    path.write_text(rendered)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
