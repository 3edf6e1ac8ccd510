"""LightningModules (GRIP++, PCT, VCT from one class) and the baselines they are compared with."""
