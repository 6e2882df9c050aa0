"""Training machinery shared by every stage: datasets, checkpoints and the Fabric loop.

``umf.train.datasets`` needs only torch (checkpoints: ``umf.checkpoint``); ``umf.train.loop``
needs the ``train`` extra (lightning-fabric). Nothing here knows about a particular model.
"""
