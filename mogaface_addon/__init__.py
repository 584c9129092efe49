"""The Blender UI layer: properties, the N-panel, preferences, registration."""
