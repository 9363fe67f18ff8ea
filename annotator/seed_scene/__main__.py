"""``python -m annotator.seed_scene`` runs ``annotator scene``."""

from annotator.cli.scene import scene_command

if __name__ == "__main__":
    scene_command()
