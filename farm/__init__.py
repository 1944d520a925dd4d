"""Bakes that outgrow one machine: batches of stages and chunked scenes on a Dask cluster.

- ``usdbake.farm.batch.bake_many``: one task per stage, on a local process pool or a Dask cluster.
- ``usdbake.farm.chunks.DaskChunks``: a large scene's work split by receivers (core.chunks), run as
  Dask tasks, the scene sent once per worker and its BVH built once per worker.
- ``usdbake.farm.cluster``: connecting to a scheduler, with one clear line when it cannot be reached.

Dask is an optional extra (``pip install -e ".[distributed]"``); nothing here imports it at module
scope, so the library works without it.
"""
