"""The gradient estimators as TorchRL ``LossModule`` s: REINFORCE, GPOMDP, ENAC (paper section 2) and PGPE."""
