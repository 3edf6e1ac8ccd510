"""The training-data layer: the gripdem HDF5 format (schema, validated reading and atomic
writing), the dataset cache, windows of a split ``h-f`` and the protocols that assign them to
train / validation / test, the encodings of the steps and their normalisation, the graph at the
last observed frame, batches, and the LightningDataModule that serves them. Everything that
reaches a model passes through here; generators and importers write this format.
"""
