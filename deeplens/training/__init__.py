"""End-to-end training: LightningModule, callbacks, metrics and ``train(cfg)``.

Importing this package pulls in Lightning and Hydra; ``deeplens.optics`` and
``deeplens.render`` never do.
"""
