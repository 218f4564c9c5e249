"""Run every bench/bench_*.py, print its figures and write them to bench-results.json.

Each module's `run() -> dict[str, tuple[float, str]]` gives figure name -> (value, unit); every
figure is printed as one line `name: value unit`. A bench that fails prints
`<bench>: FAILED (reason)` (after any figures it did measure) and the others still run; the exit
status is 1 when any failed. bench-results.json in the repository root holds every figure as
`{"name": {"value": v, "unit": "..."}}`. Entry point of `make bench`.
"""
from __future__ import annotations

import importlib
import json
import os
import sys
import traceback

import benchlib
from benchlib import BenchFailed, Figures
from cobot_calib_ros.api.dds_profile import large_data_env

RESULTS = benchlib.REPO_ROOT / 'bench-results.json'


def bench_modules() -> list[str]:
    """Module names of the benches, in name order."""
    return sorted(p.stem for p in benchlib.BENCH_DIR.glob('bench_*.py'))


def run_one(module_name: str) -> tuple[Figures, str | None]:
    """(figures, None) or (partial figures, why it failed) for one bench module."""
    try:
        return importlib.import_module(module_name).run(), None
    except BenchFailed as exc:
        return exc.partial, str(exc)
    except Exception as exc:  # noqa: BLE001 - one broken bench must not stop the others
        traceback.print_exc(file=sys.stderr)
        return {}, f'{type(exc).__name__}: {exc}'


def write_results(figures: Figures) -> None:
    """bench-results.json: {"name": {"value": v, "unit": "..."}}."""
    data = {name: {'value': value, 'unit': unit} for name, (value, unit) in figures.items()}
    RESULTS.write_text(json.dumps(data, indent=2) + '\n')


def main() -> int:
    """Run all benches; 1 when any failed."""
    # Fast DDS reads its profile file once per process, at the first participant, and every
    # bench runs in this one: the product's from the start, as cli.main sets it for every
    # command. bench_detector set it for itself after bench_bag's participants, so its 1 MB
    # images went out through 512 KB segments (44-46 % lost in transport; 0 % alone)
    os.environ.update(large_data_env())
    everything: Figures = {}
    failed = []
    for module_name in bench_modules():
        figures, error = run_one(module_name)
        for name, (value, unit) in figures.items():
            print(benchlib.format_figure(name, value, unit), flush=True)
        everything.update(figures)
        if error is not None:
            failed.append(module_name)
            print(f'{module_name.removeprefix("bench_")}: FAILED ({error})', flush=True)
    write_results(everything)
    print(f'wrote {RESULTS.name}: {len(everything)} figures'
          + (f'; failed: {", ".join(failed)}' if failed else ''), file=sys.stderr)
    return 1 if failed else 0


if __name__ == '__main__':
    sys.exit(main())
