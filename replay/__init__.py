"""rimu.replay"""

__all__: list[str] = []
