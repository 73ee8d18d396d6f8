"""Pairs of any range and size: the disparity range estimated from a coarse match (:mod:`.range`),
large pairs matched as tiles within a memory budget (:mod:`.tiling`). Many pairs in one run are
:mod:`cade_cli.batch`."""
