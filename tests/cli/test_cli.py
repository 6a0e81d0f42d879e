from __future__ import annotations

import subprocess
import sys

from coster_sumo.cli.command_line import main


def test_help_lists_commands(capsys):
    assert main([]) == 2
    assert "coster-sumo" in capsys.readouterr().out


def test_import_does_not_load_sumo_or_torch():
    code = ("import sys, coster_sumo, coster_sumo.cli.command_line; "
            "print('libsumo' in sys.modules, 'torch' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split() == ["False", "False"]


def test_global_options_work_after_the_subcommand_too():
    from coster_sumo.cli.command_line import build_parser

    parser = build_parser()
    for argv, quiet, debug in [(["run", "a.sumocfg", "--quiet"], True, False),
                               (["--quiet", "run", "a.sumocfg"], True, False),
                               (["run", "a.sumocfg", "-q", "--debug"], True, True),
                               (["run", "a.sumocfg"], False, False),
                               (["train", "rollout", "--data", "d", "-o", "o", "--debug"], False, True)]:
        args = parser.parse_args(argv)
        assert (args.quiet, args.debug) == (quiet, debug), argv
