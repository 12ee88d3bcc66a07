"""Solo-12 trotting: the bundled Raibert-style trot (stiction.controllers.TrotController) on
mu = 0.8 and on ice (mu = 0.1), in stiction and, when MuJoCo is installed, on its MuJoCo twin
driven by the same controller class through the same (q, v, t) -> control interface.

    python examples/trot.py            # 5 s on each ground
    python examples/trot.py --quick    # 1.5 s (the test suite's run)

Prints, per simulator and ground: the distance walked along the initial heading, the largest slip
of a foot's contact point during one stance (from the step after its touchdown step), the
fraction of the feet's contact steps that slid, and the real-time factor of the whole loop
(controller included).
"""
import argparse
import time

from stiction.controllers import MujocoLoop, build_controller
from stiction.simulator import Simulator


def run_stiction(scene_name: str, duration: float) -> dict:
    sim = Simulator(scene_name)
    started = time.perf_counter()
    traj = sim.rollout(duration)  # the scene's [controller] runs before every step
    wall = time.perf_counter() - started
    s = sim.summary(traj)
    touching = (traj.states == 1) | (traj.states == 2)
    return {"distance": s["distance_walked"], "slip": s["max_stance_slip"],
            "sliding": float((traj.states == 2).sum() / max(1, touching.sum())),
            "rtf": duration / wall, "converged": s["all_converged"]}


def run_mujoco(scene_name: str, duration: float) -> dict:
    scene = Simulator(scene_name).scene
    loop = MujocoLoop(scene, build_controller(scene))  # the same controller class, a fresh instance
    r = loop.run(duration)
    return {"distance": r["distance_walked"], "slip": r["max_stance_slip"],
            "sliding": float((r["tangential_speed"][r["in_contact"]] > 1e-6).mean()) if r["in_contact"].any()
            else 0.0, "rtf": r["real_time_factor"], "converged": None}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="1.5 s instead of 5 s")
    args = parser.parse_args()
    duration = 1.5 if args.quick else 5.0
    try:
        import mujoco  # noqa: F401

        simulators = {"stiction": run_stiction, "mujoco": run_mujoco}
    except ImportError:
        simulators = {"stiction": run_stiction}
        print("(MuJoCo is not installed: stiction only; pip install 'stiction[bench]' for the side by side)")
    print(f"Solo-12 trot, {duration:g} s, commanded 0.3 m/s after 0.5 s standing and a 0.5 s ramp")
    print(f"{'ground':16s} {'simulator':9s} {'distance m':>11s} {'max stance slip m':>18s} "
          f"{'sliding steps':>14s} {'real-time x':>12s}")
    for scene_name, ground in (("solo12-trot", "mu 0.8"), ("solo12-trot-ice", "mu 0.1 (ice)")):
        for name, run in simulators.items():
            r = run(scene_name, duration)
            print(f"{ground:16s} {name:9s} {r['distance']:11.4f} {r['slip']:18.3e} {r['sliding']:14.4f} "
                  f"{r['rtf']:12.2f}")
    print(f"commanded distance: {0.3 * (duration - 0.75):.4f} m")


if __name__ == "__main__":
    main()
