"""Training machinery shared by every stage: datasets, checkpoints and the Fabric loop.

``umf.train.datasets`` and ``umf.train.checkpoint`` need only torch; ``umf.train.loop``
needs the ``train`` extra (lightning-fabric). Nothing here knows about a particular model.
"""
