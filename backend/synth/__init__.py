"""Synthetic captures: procedural objects and environments, camera and light layouts, rendering."""
