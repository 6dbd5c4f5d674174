"""Adapters for the BO libraries a user might pick instead of ours (issue 16, point 4).

Each peer runs behind the tuner API (``agents.make("botorch")``, ``"skopt"``,
``"bayes-opt"``) and starts from the same Latin hypercube initial design as
``agents.make("bo")`` (:class:`agents.peers.base.PeerTuner`). The libraries are
optional: ``pip install "gbo-envs[peers]"``.
"""
