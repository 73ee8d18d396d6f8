"""Reading and writing: images and bands (:mod:`.images`), disparity maps (:mod:`.disparity`),
pictures for people (:mod:`.pictures`), registered cubes (:mod:`.registered`), outputs that
appear whole or not at all (:mod:`.atomic`), file digests (:mod:`.checksum`)."""
