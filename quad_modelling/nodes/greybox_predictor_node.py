"""``greybox_predictor``: the generic :mod:`~quad_modelling.nodes.predictor_node` with ``model`` defaulting to ``greybox``."""

from __future__ import annotations

from quad_modelling.nodes.common import run_node
from quad_modelling.nodes.predictor_node import PredictorNode


class GreyboxPredictorNode(PredictorNode):
    """Live greybox predictor (publishes ``greybox/odom`` and ``greybox/accel``)."""

    def __init__(self, **kwargs):
        super().__init__("greybox_predictor", "greybox", **kwargs)


def main(args=None) -> int:
    return run_node(GreyboxPredictorNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
