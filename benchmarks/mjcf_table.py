"""The table of docs/mjcf.md: every MJCF file of a folder (dm_control's suite) loaded with
Pinocchio's parser through stiction.mjcf and compared with MuJoCo's model of the same file.

    pip download dm-control==1.0.52 --no-deps -d /tmp/dmc && unzip -q /tmp/dmc/dm_control-*.whl -d /tmp/dmc
    python benchmarks/mjcf_table.py /tmp/dmc/dm_control/suite > /tmp/mjcf-table.md

Needs MuJoCo (pip install mujoco==4.0.*). Prints a Markdown table, one row per model.
"""
from __future__ import annotations

import sys
from pathlib import Path

import mujoco
import pinocchio as pin

from stiction.mjcf import MjcfMismatch, compare_with_mujoco, load_mjcf, mujoco_model, total_mass


def row(path: Path) -> str:
    mj = mujoco_model(path)
    mujoco_text = f"{mj.nq} / {mj.nv} / {sum(mj.body_mass):.4g}"
    try:
        robot = load_mjcf(path, check=False)
    except MjcfMismatch as exc:
        reason = str(exc).split("parser fails: ")[-1]
        return f"| {path.stem} | fails: {reason} | {mujoco_text} | refused |"
    model = robot.model
    found = compare_with_mujoco(model, path)
    ours = f"{model.nq} / {model.nv} / {total_mass(model):.4g}"
    if robot.total_mass_scale != 1.0:
        unscaled = total_mass(model) / robot.total_mass_scale
        ours += f" (settotalmass applied; Pinocchio alone: {unscaled:.4g})"
    verdict = "exact" if not found else "refused: " + "; ".join(found.values())
    return f"| {path.stem} | {ours} | {mujoco_text} | {verdict} |"


def main(folder: str) -> None:
    print(f"| model | Pinocchio {pin.__version__} nq / nv / mass (kg) | MuJoCo {mujoco.__version__} nq / nv / "
          "mass (kg) | stiction.mjcf |")
    print("|---|---|---|---|")
    for path in sorted(Path(folder).glob("*.xml")):
        root = path.read_text()
        if "<worldbody" not in root:  # included pieces (common/*.xml), not models
            continue
        print(row(path))


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "robots/mjcf/dm_control")
