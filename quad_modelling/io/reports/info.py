"""What a bag or flight log holds, as ``quad-modelling info`` prints it: a JSON document or a text listing.

Times in s from the log's own clock (a bag's header stamps), rates in Hz.
"""

from __future__ import annotations

import json
from dataclasses import asdict

from quad_modelling.core.flight_log import FlightLog
from quad_modelling.io.bag_io import BagSummary

FLIGHT_FIELDS = ("u", "acc_b", "gyro_b", "pos_n", "vel_n", "euler", "vbat", "omega")
"""FlightLog arrays a flight may hold, in the order the listing names them."""

def flight_document(log: FlightLog, path: str) -> dict:
    """A flight log's summary: vehicle, samples, duration, rate, time span, the arrays it holds, its notes."""
    return {
        "path": path,
        "vehicle": log.meta.vehicle,
        "samples": len(log),
        "duration_s": log.duration,
        "rate_hz": log.sample_rate,
        "start_s": float(log.t[0]),
        "end_s": float(log.t[-1]),
        "fields": [name for name in FLIGHT_FIELDS if getattr(log, name) is not None],
        "notes": log.meta.notes,
    }


def flight_json(document: dict) -> str:
    """:func:`flight_document` as JSON; notes that are not JSON types are written as their text."""
    return json.dumps(document, indent=2, default=str)


def flight_text(document: dict, file_format: str) -> str:
    """:func:`flight_document` as the info listing; ``file_format`` as :func:`quad_modelling.io.loader.detect_format` names it."""
    lines = [f"flight:    {document['path']} ({file_format})",
             f"vehicle:   {document['vehicle']}",
             f"samples:   {document['samples']} at {document['rate_hz']:.2f} Hz, duration {document['duration_s']:.3f} s",
             f"start/end: {document['start_s']:.3f} .. {document['end_s']:.3f} s",
             f"fields:    {', '.join(document['fields'])}"]
    for key, value in document["notes"].items():  # a simulated flight's effects and seed; a PX4 log's sources and rates
        if isinstance(value, dict):
            lines.append(f"{key}:")
            lines += [f"  {name + ':':<15} {entry}" for name, entry in value.items()]
        else:
            lines.append(f"{key + ':':<10} {value}")
    return "\n".join(lines)


def bag_json(summary: BagSummary) -> str:
    """The bag summary as JSON, each topic with its rate [Hz]."""
    document = asdict(summary)
    for topic, entry in zip(summary.topics, document["topics"]):
        entry["rate_hz"] = topic.rate_hz
    return json.dumps(document, indent=2)


def bag_text(summary: BagSummary) -> str:
    """The bag summary as the info listing: storage, duration, messages, vehicle/source, one line per topic."""
    lines = [f"bag:       {summary.path}",
             f"storage:   {summary.storage}",
             f"duration:  {summary.duration_s:.3f} s",
             f"start/end: {summary.start_s:.3f} .. {summary.end_s:.3f} s (bag time: when recorded; the header stamps in the bags quad-modelling writes)",
             f"messages:  {summary.message_count}"]
    lines += [f"{key + ':':<10} {summary.custom_data[f'quad_modelling.{key}']}"
              for key in ("vehicle", "source") if f"quad_modelling.{key}" in summary.custom_data]
    width = max([5, *(len(t.name) for t in summary.topics)])
    types = max([28, *(len(t.msgtype) for t in summary.topics)])  # crazyflie_interfaces/msg/LogDataGeneric is 38
    lines += ["", f"{'topic':<{width}}  {'type':<{types}} {'count':>7} {'rate Hz':>8} {'span s':>8}"]
    lines += [f"{t.name:<{width}}  {t.msgtype:<{types}} {t.count:>7} {t.rate_hz:>8.2f} {t.end_s - t.start_s:>8.2f}" for t in summary.topics]
    return "\n".join(lines)
