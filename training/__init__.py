"""The CNN surrogate (paper sections 6-8, DESIGN section 8): data, networks, training, inference.

- :mod:`training.data`: a lazy torch Dataset over an amfe data set, seeded
  splits, label normalisation, label-preserving symmetries.
- :mod:`training.nets`: Custom Net, LeNet-5, AlexNet and VGG with a six-output
  linear regression head.
- :mod:`training.train`: training one network or a seeded ensemble.
- :mod:`training.checkpoint`: plain-data checkpoints, loaded weights-only.
- :mod:`training.predict`: inference on images and beds, the ensemble flag.
- :mod:`training.metrics`, :mod:`training.plots`: errors per property, curves.

This module imports nothing heavy, so the amfe command line can build its
parsers without importing torch.
"""
ARCH_NAMES = ("custom", "lenet5", "alexnet", "vgg")
AUGMENTATIONS = ("none", "flips", "d4")
SCHEDULES = ("constant", "cosine")
