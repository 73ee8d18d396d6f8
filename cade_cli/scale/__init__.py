"""Pairs of any size and any number: the disparity range estimated from a coarse match
(:mod:`.range`), large pairs matched as tiles within a memory budget (:mod:`.tiling`), many pairs
on worker processes or a Dask cluster (:mod:`.batch`)."""
