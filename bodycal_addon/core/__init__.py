"""Foundations every layer uses: errors, rigid transforms, fits, paths and safe output files."""
