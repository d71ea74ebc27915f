"""The CNN surrogate (paper sections 6-8, docs/model.md section 8): data, networks, training, use.

- :mod:`amfe.training.data`: a lazy torch Dataset over an amfe data set, seeded
  splits, label normalisation, label-preserving symmetries.
- :mod:`amfe.training.nets`: Custom Net, LeNet-5, AlexNet and VGG with a six-output
  linear regression head.
- :mod:`amfe.training.multiscale`: a multi-scale encoder that reads the holes.
- :mod:`amfe.training.train`: training one network or a seeded ensemble.
- :mod:`amfe.training.checkpoint`: plain-data checkpoints, loaded weights-only.
- :mod:`amfe.training.predict`: inference on images and beds, the ensemble flag.
- :mod:`amfe.training.metrics`, :mod:`amfe.training.plots`: errors per property, curves.
- :mod:`amfe.training.stiffness`, :mod:`amfe.training.stiffness_fit`: the full stiffness
  through a Cholesky head, its tensor symmetries, fitting and saving such models.
- :mod:`amfe.training.stiffness_train`, :mod:`amfe.training.stiffness_predict`: a stiffness
  head on a trained multi-scale model (``amfe train --head stiffness``) and its prediction
  through the same Surrogate / amfe predict path.
- :mod:`amfe.training.anysize`: a fully convolutional net for any bed size, the whole-cell rule.
- :mod:`amfe.training.conformal`: split conformal intervals per bed size.

This module imports nothing heavy, so the amfe command line can build its
parsers without importing torch.
"""
ARCH_NAMES = ("custom", "lenet5", "alexnet", "vgg", "multiscale")
AUGMENTATIONS = ("none", "flips", "d4")
SCHEDULES = ("constant", "cosine")
LOSSES = ("mse", "l1")
