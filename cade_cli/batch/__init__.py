"""Many jobs in one run (``cade batch``): pairs (:mod:`.pairs`, one pair's job :mod:`.job`) and a
drone flight's captures (:mod:`.captures`), run by the engines of :mod:`.engines` (worker
processes or a Dask cluster) with a JSON log (:mod:`.log`). Above rigs/, scale/, capture/ and the
evaluation, whose work its jobs run."""
