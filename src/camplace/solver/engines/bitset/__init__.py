"""The bound-pruned search over tuples of candidate clusters on row bitsets (``exact``), and the
opposite-pairs bound of multiview."""
