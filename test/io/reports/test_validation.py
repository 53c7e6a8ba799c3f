"""Validation report text: exact tables of validation.md and the one-line summary from a known validation document."""

from quad_modelling.io.reports.validation import validation_markdown, validation_summary


def _validation():
    return {"vehicle": "linkquad", "accuracy": 0.5, "pairs_accuracy": None,
            "runs": [{"effect": "battery", "seed": 0, "top": "battery", "correct": True, "shrink": 0.457, "sensor_ceiling": 0.526,
                      "variables": ["acc_z"], "attributable_share": 0.483, "attributable_removed": None, "verdict": "found",
                      "top_shrinks": {"battery": 0.457, "rotor_drag": 0.002}},
                     {"effect": "motor_lag", "seed": 0, "top": "battery", "correct": False, "shrink": 0.01, "verdict": "insignificant",
                      "top_shrinks": {}}],
            "null": {"found": ["trim_drift"], "runs": [{"seed": 0, "found": [], "top_shrinks": {"battery": -0.01}}]},
            "pairs": [],
            "shrink_by_effect": {"battery": {"min": 0.1, "median": 0.2, "max": 0.3}}}


def test_validation_tables():
    lines = validation_markdown(_validation()).splitlines()
    assert lines[2] == ("Accuracy (right effect ranked first and found): **50%** over 2 (effect, seed) runs; null case found: trim_drift; "
                        "pairs both found in top 3: -.")
    first = lines.index("| effect | held-out shrink min / median / max | sensor ceiling min / median / max | attributable min / median "
                        "| removed min / median |")
    assert lines[first + 1:first + 4] == ["|---|---|---|---|---|", "| battery | 10.0% / 20.0% / 30.0% | - / - / - | - / - | - / - |", ""]
    assert lines[first + 4:] == [
        "| effect | seed | top | correct | held-out shrink | sensor ceiling | scored on | attributable | removed | verdict | ranking |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
        "| battery | 0 | battery | yes | 45.7% | 52.6% | acc_z | 48.3% | - | found | battery 45.7%, rotor_drag 0.2% |",
        "| motor_lag | 0 | battery | no | 1.0% | - | - | - | - | insignificant |  |",
        "",
        "| null seed | found | top shrinks |",
        "|---|---|---|",
        "| 0 | - | battery -1.0% |",
    ]


def test_validation_summary_line():
    assert validation_summary(_validation()) == "accuracy 50% over 2 runs; null case found trim_drift; pairs -"
