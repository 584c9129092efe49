"""What Blender calls back rather than the user: the viewport draw handler and the head re-posing handlers."""
