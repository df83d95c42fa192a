"""dgtd: distributed policy evaluation with the primal-dual distributed GTD method and its baselines."""

__version__ = "0.1.0"
