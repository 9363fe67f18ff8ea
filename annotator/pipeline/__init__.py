"""The labelling runner: jobs (objects, given grasps; scenes are :mod:`annotator.pipeline.scene_job`) run
by one lifecycle (:mod:`.lifecycle`) on local workers or Dask (:mod:`.execution`); the one worker
state every task runs through (:mod:`.worker`), its modes (:mod:`.modes`: the object modes in
:mod:`.object_modes`, the scene's in :mod:`.scene_mode`), a span's trials and rows
(:mod:`.simulate`) and the records between them (:mod:`.tasks`). docs/architecture.md draws the
map."""
