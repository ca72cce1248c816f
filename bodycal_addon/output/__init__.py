"""What a retargeted animation becomes: root motion, Rigify targets, key reduction, metrics."""
