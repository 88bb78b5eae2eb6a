"""The file-system layer: atomic writes, safe opening of inputs, output folders replaced as one unit under a lock."""
