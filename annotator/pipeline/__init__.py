"""The labelling runner: jobs (objects, given grasps; scenes are :mod:`annotator.pipeline.scene_job`) run
by one lifecycle (:mod:`.lifecycle`) on local workers or Dask (:mod:`.execution`); the worker's
state (:mod:`.worker`), its modes (:mod:`.modes`), a span's trials and rows (:mod:`.simulate`) and
the records between them (:mod:`.tasks`). docs/architecture.md draws the map."""
