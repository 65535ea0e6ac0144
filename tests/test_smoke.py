import subprocess
import sys

HEAVY = ("torch", "scenes", "trimesh", "ebad.run")  # not needed to show the help


def test_cli_help_lists_commands():
    out = subprocess.run([sys.executable, "-m", "ebad", "--help"], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert "usage: ebad" in out.stdout and out.stdout.count("usage:") == 1
    for name in ("deblur", "demo", "eval", "reconstruct", "render", "synth", "video", "view"):
        assert name in out.stdout


def test_help_imports_no_heavy_module():
    # ``ebad --help`` and a subcommand's help stay quick: the heavy modules are imported by the commands' run
    code = (
        "import sys\nfrom ebad.cli import main\n"
        "assert main(['--help']) == 0 and main(['reconstruct', '--help']) == 0 and main(['synth', '--help']) == 0\n"
        f"print([m for m in {HEAVY!r} if m in sys.modules])"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().splitlines()[-1] == "[]"
