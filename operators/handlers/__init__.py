"""What Blender calls back rather than the user: the viewport's draw handler, the handlers that re-pose
heads (frame change, edits) and the one that fills the avatar layers before a render."""
