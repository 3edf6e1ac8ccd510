"""Neural building blocks: sparse graph-conv encoder and seq2seq GRU trajectory decoder."""
