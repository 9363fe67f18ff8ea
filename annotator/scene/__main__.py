"""``python -m annotator.scene`` runs ``annotator scene``."""

from annotator.scene.command import scene_command

if __name__ == "__main__":
    scene_command()
