"""rimu.thresholds"""

__all__: list[str] = []
