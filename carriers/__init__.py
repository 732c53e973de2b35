"""The carrier process: drives its own body in its own copy of the world, senses, publishes,
waits for the stage's decision, deploys and confirms. See carriers/node.py and docs/fleet.md."""
