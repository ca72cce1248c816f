"""Avatars measured from their armature and mesh, or estimated from bone lengths."""
