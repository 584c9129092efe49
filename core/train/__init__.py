"""Training an avatar on a capture: config, losses, schedules, checkpoints, the trainer loop."""
