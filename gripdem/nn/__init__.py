"""Neural building blocks with documented tensor shapes: the paper's sparse graph-convolution
encoder, the contact encoder (message passing with pair messages from relative geometry and
motion), and the seq2seq GRU trajectory decoder. Plain ``torch.nn`` modules that know nothing of
files, boundaries or Lightning.
"""
