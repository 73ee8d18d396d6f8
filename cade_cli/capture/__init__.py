"""Drone multispectral captures (one lens per band) registered onto their reference band with
parallax: the files' metadata (:mod:`.metadata`, :mod:`.lens`), the capture as a rig
(:mod:`.model`), the plane and the parallax the sparse matches show (:mod:`.parallax`), the
registration (:mod:`.register`) and its files (:mod:`.cube`); a flight folder's captures
(:mod:`.flight`); the vendors' one-homography alignment (:mod:`.homography`) and a
no-ground-truth alignment measure (:mod:`.alignment`). docs/drone.md.
"""
