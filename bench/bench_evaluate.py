"""Evaluation speed and accuracy: a simulated 220 s LinkQuad flight and the real NanoBench flights.

Target (issue 4): evaluating a 220 s, 100 Hz flight (12 training + 4 evaluation windows,
greybox + dummy, plus the multi-step table) in under 2 s; one 10 s greybox window well
under 10 ms. Reports the thesis-style accuracy tables for both data sets, with motor
constants identified on the training spans. Writes bench/results/evaluate.{json,md}.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import SHARED_DATA, median_seconds, write_results  # noqa: E402
from quad_modelling.core.evaluation.windowed import evaluate  # noqa: E402
from quad_modelling.core.identification.identify import identify  # noqa: E402
from quad_modelling.core.models.greybox import GreyboxPredictor  # noqa: E402
from quad_modelling.core.models.registry import make_model  # noqa: E402
from quad_modelling.core.vehicle import load_vehicle  # noqa: E402
from quad_modelling.core.windows import EvaluationConfig
from quad_modelling.errors import QuadModellingError  # noqa: E402
from quad_modelling.io.loader import load_flight  # noqa: E402
from quad_modelling.io.reports.evaluation import markdown_tables  # noqa: E402

HEADLINE = ("acc_z", "roll_rate", "vel_z", "yaw_rate")


def headline(result) -> dict:
    data = result.to_json()["models"]
    return {m: {v: round(data[m]["eval"][v]["tic"], 3) for v in HEADLINE} for m in data if "eval" in data[m]}


def data_set(name, flights, vehicle, config) -> tuple[dict, str]:
    identified = identify(flights, vehicle, config)
    tuned = vehicle.with_values(identified.values, "identified (bench)")
    if identified.spins and list(identified.spins) != list(tuned.yaw_signs):
        from quad_modelling.core.identification.identify import vehicle_with_spins

        tuned = vehicle_with_spins(tuned, identified.spins)
    models = [make_model("greybox", tuned), make_model("dummy", tuned)]
    seconds, runs = median_seconds(lambda: evaluate(flights, models, tuned, config), repeats=3)
    result = evaluate(flights, models, tuned, config)
    table = markdown_tables(result, f"{name} (greybox with identified constants)")
    entry = {
        "flights": len(flights), "evaluation_seconds": seconds, "runs": runs,
        "identified": identified.values, "identified_sigma": identified.sigma,
        "motor_check_consistent": identified.motor_check["consistent"], "spins_reversed": identified.motor_check["yaw_reversed"],
        "voltage_dependence": identified.voltage, "eval_tic": headline(result), "results": result.to_json(),
    }
    return entry, table


def main_bench() -> None:
    from quad_modelling.core.sim.simulate import simulate

    linkquad = load_vehicle("linkquad")
    sim_log = simulate("linkquad", effects=(), seed=1, duration=220.0)
    window = sim_log.slice(3000, 4000)
    predictor = GreyboxPredictor(linkquad)
    window_seconds, _ = median_seconds(lambda: predictor.predict_window(window, 20), repeats=20)
    data = {"greybox_window_10s_seconds": window_seconds}
    sim_entry, sim_table = data_set("Simulated LinkQuad flight (220 s, effects off, seed 1)", [sim_log], linkquad, EvaluationConfig())
    data["linkquad_sim"] = sim_entry
    md = [
        "# bench_evaluate", "",
        f"- one 10 s greybox window (1000 samples): {window_seconds * 1e3:.2f} ms (target well under 10 ms)",
        f"- evaluate a 220 s simulated LinkQuad flight (greybox + dummy, 16 windows, multi-step): "
        f"{sim_entry['evaluation_seconds']:.2f} s (target < 2 s)",
    ]
    tables = [sim_table]
    nanobench = sorted((SHARED_DATA / "nanobench").glob("*.csv.gz"))
    if nanobench:
        flights, skipped = [], []
        for path in nanobench:
            try:
                flights.append(load_flight(path))
            except QuadModellingError as err:
                skipped.append(str(err))
        nb_entry, nb_table = data_set(f"NanoBench Crazyflie 2.1 ({len(flights)} flights, preset short)", flights,
                                      load_vehicle("crazyflie21"), EvaluationConfig.preset("short"))
        nb_entry["skipped"] = skipped
        data["nanobench"] = nb_entry
        md.append(f"- evaluate {len(flights)} NanoBench flights: {nb_entry['evaluation_seconds']:.2f} s "
                  f"(skipped {len(skipped)}: quirky file refused by the reader)")
    md += ["", "## Headline TIC on the evaluation span", "", "| data set | model | " + " | ".join(HEADLINE) + " |",
           "|---|---|" + "---|" * len(HEADLINE)]
    for key in ("linkquad_sim", "nanobench"):
        if key in data:
            for model, values in data[key]["eval_tic"].items():
                md.append(f"| {key} | {model} | " + " | ".join(f"{values[v]:.2f}" for v in HEADLINE) + " |")
    md += ["", "## Identified constants", ""]
    for key in ("linkquad_sim", "nanobench"):
        if key in data:
            e = data[key]
            md.append(f"- {key}: " + ", ".join(f"{k} = {v:.4g} ± {e['identified_sigma'][k]:.2g}" for k, v in e["identified"].items())
                      + f"; motor layout consistent with config: {e['motor_check_consistent']}, spins reversed: {e['spins_reversed']}")
    md += [""] + [t.replace("# ", "## ", 1) for t in tables]
    if "nanobench" in data:
        md.append(nb_table.replace("# ", "## ", 1))
    md.append(f"\n(run {time.strftime('%Y-%m-%d %H:%M')})")
    write_results("evaluate", data, "\n".join(md))


if __name__ == "__main__":
    main_bench()
