"""Capture the golden lockstep and offline results (run once, on a commit known to be right).

    python tests/golden/capture.py            # rewrites tests/golden/*.json

A golden result is the deterministic part of a flight's summary plus SHA-256 digests of its
true trajectory and of the commands the vehicle applied, so "bit-identical" is checked on the
whole flight, not on a handful of numbers. Refactors that are not meant to change behaviour
must leave these files untouched (tests/golden/test_golden.py compares).
"""

from __future__ import annotations

import json
import tempfile
from pathlib import Path

from tfl_mav.tools.harness.golden import (
    LOCKSTEP_CASES,
    OFFLINE_CASES,
    fly_lockstep,
    fly_offline_case,
)

HERE = Path(__file__).resolve().parent


def main() -> None:
    offline = {name: fly_offline_case(*case) for name, case in OFFLINE_CASES.items()}
    (HERE / "offline.json").write_text(json.dumps(offline, indent=1, sort_keys=True) + "\n")
    print("offline:", json.dumps(offline, indent=1))
    lockstep = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name, case in LOCKSTEP_CASES.items():
            lockstep[name] = fly_lockstep(*case, out=Path(tmp) / name)
            print(name, json.dumps(lockstep[name]))
    (HERE / "lockstep.json").write_text(json.dumps(lockstep, indent=1, sort_keys=True) + "\n")


if __name__ == "__main__":
    main()
