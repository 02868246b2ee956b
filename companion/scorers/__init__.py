"""The built-in frame scorers, one module each; ``companion.scoring`` is their registry."""
