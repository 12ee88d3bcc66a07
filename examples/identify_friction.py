"""Identify a friction coefficient and a mass from a recorded trajectory, through the step's derivatives.

A 1 kg cube slides on flat ground (μ = 0.5) pushed by a known force; its trajectory is recorded with
motion-capture noise (10 µm, 0.1 mm/s). From a wrong guess (μ = 0.3, m = 1.5 kg), Gauss-Newton on the
trajectory error recovers both: μ's sensitivity is chained through the steps,
dx_{k+1}/dμ = F_k dx_k/dμ + f_μ, with ``Simulator.step_derivatives()`` when this build has it
(``--derivatives analytic``) or central differences of the step (``--derivatives fd``); the mass's by
differences of the whole trajectory (the step's derivatives do not include it). Then the same for
Solo-12 (joints locked) slipping down a 20° slope with a 0.5 kg payload (``stiction casestudy
identify-friction`` runs both with its checks).

Run from anywhere: python examples/identify_friction.py [--derivatives fd|analytic] [--quick]
"""
import argparse

from stiction.casestudies import identify_friction as cs

parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("--derivatives", choices=cs.DERIVATIVES, default=None,
                    help="analytic (Simulator.step_derivatives) or fd; default: analytic when built")
parser.add_argument("--quick", action="store_true", help="the cube only, a shorter recording")
args = parser.parse_args()
derivatives = args.derivatives or cs.default_derivatives()
print(f"step derivatives: {derivatives}")
for exp in cs.experiments(quick=args.quick)[: 1 if args.quick else None]:
    q_meas, v_meas = cs.record(exp)
    mu, mass, iterations, history = cs.identify(exp, q_meas, v_meas, derivatives)
    label = "payload" if exp.payload else "mass"
    for row in history:
        print(f"  {exp.name} iteration {row['iteration']}: mu {row['mu']:.8f}, {label} {row['mass']:.8f} kg, "
              f"cost {row['cost']:.6g}")
    print(f"{exp.name}: mu {mu:.8f} (true {exp.mu}), relative error {abs(mu - exp.mu) / exp.mu:.3e}")
    print(f"{exp.name}: {label} {mass:.8f} kg (true {exp.mass}), relative error {abs(mass - exp.mass) / exp.mass:.3e}")
    print(f"{exp.name}: {iterations} Gauss-Newton iterations")
