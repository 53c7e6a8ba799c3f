"""Figure of one simulated flight: engine inputs, attitude, position, battery, rotor speeds.

    .venv/bin/python bench/plot_sim.py [-o docs/sim_flight.png] [--vehicle linkquad] [--seed 0]
        [--effects default] [--duration 220] [--force]

Writes a PNG (Agg backend) through the package's atomic output rule (no
overwrite without --force).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from quad_modelling.atomic import atomic_output  # noqa: E402
from quad_modelling.core.effect_names import SIMULATOR, parse_effect_names  # noqa: E402
from quad_modelling.core.flight_log import FlightLog  # noqa: E402
from quad_modelling.core.sim.simulate import run_simulation  # noqa: E402


def plot_flight(log: FlightLog, path: str | Path, input_unit: str, force: bool = False, title: str = "") -> Path:
    """Five stacked panels over time: u (in µs when the unit is s), roll/pitch/yaw [deg],
    position NED [m] (height = -z), battery voltage [V], rotor speeds [rad/s]."""
    t = log.t
    fig, axes = plt.subplots(5, 1, figsize=(12, 13), sharex=True)
    scale, label = (1e6, "us") if input_unit == "s" else (1.0, input_unit)
    for i in range(4):
        axes[0].plot(t, log.u[:, i] * scale, lw=0.6, label=f"u{i + 1}")
    axes[0].set_ylabel(f"engine command [{label}]")
    flying = log.u.min(axis=1) > np.percentile(log.u, 20)
    if flying.any():
        lo, hi = np.percentile(log.u[flying] * scale, [0.5, 99.5])
        pad = 0.15 * (hi - lo)
        axes[0].set_ylim(lo - pad, hi + pad)
    for i, name in enumerate(("roll", "pitch", "yaw")):
        axes[1].plot(t, np.rad2deg(log.euler[:, i]), lw=0.7, label=name)
    axes[1].set_ylabel("attitude [deg]")
    for i, name in enumerate(("x north", "y east")):
        axes[2].plot(t, log.pos_n[:, i], lw=0.8, label=name)
    axes[2].plot(t, -log.pos_n[:, 2], lw=0.8, label="height (-z)")
    axes[2].set_ylabel("position [m]")
    if log.vbat is not None:
        axes[3].plot(t, log.vbat, lw=0.6, color="tab:red")
    axes[3].set_ylabel("battery [V]")
    if log.omega is not None:
        for i in range(4):
            axes[4].plot(t, log.omega[:, i], lw=0.6, label=f"rotor {i + 1}")
    axes[4].set_ylabel("rotor speed [rad/s]")
    axes[4].set_xlabel("time [s]")
    for ax in axes:
        ax.grid(alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(loc="upper right", fontsize=8, ncol=4)
        for edge in (30.0, 150.0, 190.0):
            if t[0] < edge < t[-1]:
                ax.axvline(edge, color="k", lw=0.5, ls="--", alpha=0.4)
    fig.suptitle(title or f"simulated flight ({log.meta.vehicle})")
    fig.tight_layout()
    path = Path(path)
    with atomic_output(path, force) as tmp:
        fig.savefig(tmp, dpi=90, format="png")
    plt.close(fig)
    return path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("-o", "--output", default="docs/sim_flight.png")
    parser.add_argument("--vehicle", default="linkquad")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--effects", default="default")
    parser.add_argument("--duration", type=float, default=220.0)
    parser.add_argument("--force", action="store_true")
    args = parser.parse_args(argv)
    effects = parse_effect_names(args.effects, SIMULATOR)
    result = run_simulation(args.vehicle, effects, args.seed, args.duration, progress=True)
    title = f"simulated {args.vehicle} flight, seed {args.seed} (dashed: thesis spans 30/150/190 s)\neffects: {', '.join(effects) or 'none'}"
    path = plot_flight(result.log, args.output, result.params.vehicle.input_unit, args.force, title)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
