"""Blender operators: thin, they translate Blender state to and from core calls."""
