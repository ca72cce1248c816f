"""Tracker recordings: the model, coordinates, segments, gaps, roles, filters and readers."""
