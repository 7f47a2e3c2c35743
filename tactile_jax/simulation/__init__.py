"""The space-domain scene simulator: textures sliding under a contact window over the probes."""
