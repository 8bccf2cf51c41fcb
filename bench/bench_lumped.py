"""η-model ranking and LS σ against the Monte-Carlo spread (SPEC C9, §3.8), plus the inertia
regression over noise levels. Prints numbers; no pass/fail.

    /tmp/venv/bin/python bench/bench_lumped.py [--runs N]
"""
from __future__ import annotations

import argparse
import collections
import math
import time

import numpy as np

from companion.numerics import lumped
from harness.datasets import ETA, J_LS, K_R, NOISE, romeo_points, surge_experiment


def eta_models(runs: int, kq: float, k: float, noise: float, label: str) -> None:
    start = time.perf_counter()
    per_model: dict[str, list] = collections.defaultdict(list)
    best, champion = collections.Counter(), collections.Counter()
    for seed in range(runs):
        fits = lumped.fit_eta_models(*romeo_points(seed, k=k, kq=kq, noise=noise))
        for name, fit in fits.items():
            per_model[name].append((fit.fit.theta, fit.fit.sigma, fit.j_ls))
        choice = lumped.select_model(fits)
        best[choice["best"]] += 1
        champion[choice["min_j_per_dof"]] += 1
    print(f"== {label}: {runs} Monte-Carlo runs ({time.perf_counter() - start:.1f} s)")
    for name, rows in per_model.items():
        theta = np.array([r[0] for r in rows])
        sigma = np.array([r[1] for r in rows])
        j = np.array([r[2] for r in rows])
        names = lumped.fit_eta_model(name, *romeo_points(0)).names
        parts = []
        for i, p in enumerate(names):
            spread = theta[:, i].std(ddof=1)
            predicted = math.sqrt(np.mean(sigma[:, i] ** 2))
            parts.append(f"{p} {theta[:, i].mean():.4g} (σ LS {predicted:.3g} / MC {spread:.3g} = {predicted / spread:.2f})")
        print(f"  η{name:5s} J_LS {j.mean():.3g}: " + "; ".join(parts))
    print(f"  chosen (J_LS/ν + F-test guard): {dict(best)}")
    print(f"  smallest J_LS/ν alone:          {dict(champion)}")


def inertia(runs: int) -> None:
    t, x, u, force = surge_experiment()
    print(f"== inertia (ROMEO surge: m 675 kg, k 38, k_q 333, f = 35 + 20 sin(ω_opt t), 10 Hz, {runs} runs)")
    for noise in (0.0005, 0.002, 0.01):
        masses, sigmas = [], []
        for seed in range(runs):
            rng = np.random.default_rng(seed)
            fit = lumped.fit_inertia(t, x + rng.normal(0, noise, t.size), force, 38.0, 333.0, savgol_window=41)
            masses.append(fit.mass)
            sigmas.append(fit.mass_sigma)
        print(f"  position noise {1000 * noise:4.1f} mm: mass {np.mean(masses):7.2f} kg (bias {np.mean(masses) - 675:+.2f}), "
              f"MC spread {np.std(masses, ddof=1):.2f}, LS σ {math.sqrt(np.mean(np.square(sigmas))):.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=1000)
    args = parser.parse_args()
    print(f"truth (SPEC §3.8, Watson exp. B): k_r {K_R}, η {ETA}, noise σ {NOISE:.3f} N·m (J_LS {J_LS} at ν 12)")
    eta_models(args.runs, 0.0, K_R, NOISE, "truth ηLNB")
    eta_models(args.runs, 400.0, 20.0, 0.2, "truth ηLQNB (k 20, k_q 400, σ 0.2)")
    inertia(max(20, args.runs // 20))


if __name__ == "__main__":
    main()
