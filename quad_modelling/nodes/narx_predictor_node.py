"""``narx_predictor``: the generic :mod:`~quad_modelling.nodes.predictor_node` with ``model`` defaulting to ``narx``.

The NARX model needs its file: ``-p model_file:=model.npz`` (or ``-p model:=narx:model.npz``)."""

from __future__ import annotations

from quad_modelling.nodes.common import run_node
from quad_modelling.nodes.predictor_node import PredictorNode


class NarxPredictorNode(PredictorNode):
    """Live narx predictor (publishes ``narx/odom`` and ``narx/accel``)."""

    def __init__(self, **kwargs):
        super().__init__("narx_predictor", "narx", **kwargs)


def main(args=None) -> int:
    return run_node(NarxPredictorNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
