"""The models: one LightningModule for GRIP++, PCT and VCT (on the contact encoder by default),
whose decoder mode and encoder come from config; how each decoder mode feeds, advances, decodes
and trains the GRU; the validation and test steps that score rollouts beside the baselines; and
the baselines themselves (stay, constant velocity, the linear autoregressive filter, the
mean-flow profile).
"""
