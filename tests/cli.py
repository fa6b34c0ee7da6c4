"""Running ``vpr`` in the test process, and what a refused run must look like (one line, status 2)."""
from pipelines.cli import main


def run(argv, capsys):
    """``vpr ARGV --no-progress`` in this process: (status, stdout, stderr)."""
    code = main([str(a) for a in argv] + ["--no-progress"])
    cap = capsys.readouterr()
    return code, cap.out, cap.err


def one_error_line(code, err, *expect):
    """A refused run: status 2 and one line on stderr holding every string of ``expect``; returns the line."""
    lines = err.strip().splitlines()
    assert code == 2, err
    assert len(lines) == 1, err
    for e in expect:
        assert e in lines[0], lines[0]
    return lines[0]
