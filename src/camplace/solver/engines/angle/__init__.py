"""The exact multiview engine with a minimum triangulation angle."""
