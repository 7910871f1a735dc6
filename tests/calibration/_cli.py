"""The CLI called in-process by the calibration command tests."""

from rimu.cli import main


def run(capsys, *argv):
    """``rimu ARGV...`` in-process: (exit code, stdout, stderr)."""
    code = main([str(a) for a in argv])
    out = capsys.readouterr()
    return code, out.out, out.err
