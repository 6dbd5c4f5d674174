"""Run every benchmark script in this folder and collect their JSON into one file.

Usage: ``python benchmarks/run_all.py [--out DIR] [--only NAME ...]``. Each
``bench_*.py`` prints one JSON object on stdout; they are saved as
``DIR/<name>.json`` and summarised in ``DIR/summary.json``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path


def _last_json(stdout: str):
    """The JSON object a benchmark printed: the whole output, or else its last line."""
    try:
        return json.loads(stdout)
    except json.JSONDecodeError:
        return json.loads(stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("out/bench"), help="folder for the JSON files")
    parser.add_argument("--only", nargs="*", default=None, help="benchmark names (e.g. bench_simulation)")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    scripts = sorted(Path(__file__).parent.glob("bench_*.py"))
    if args.only:
        scripts = [s for s in scripts if s.stem in args.only]
    summary, failed = {}, []
    for script in scripts:
        print(f"== {script.stem}", flush=True)
        done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True)
        if done.returncode != 0:
            print(done.stderr, file=sys.stderr)
            failed.append(script.stem)
            continue
        result = _last_json(done.stdout)
        (args.out / f"{script.stem}.json").write_text(json.dumps(result, indent=2))
        summary[script.stem] = result
        print(json.dumps(result, indent=2), flush=True)
    (args.out / "summary.json").write_text(json.dumps(summary, indent=2))
    if failed:
        print(f"failed: {', '.join(failed)}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
