"""The canonical body: skeleton, naming schemes, body models, surface layout, animations."""
