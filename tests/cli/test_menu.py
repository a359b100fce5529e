"""The subcommand dispatcher (trainer.menu) and every menu built on it."""

from __future__ import annotations

import pytest

from trainer.menu import Menu, command_line, load


class Refused(ValueError):
    pass


def echo(argv: list[str]) -> int:
    print("echo", *argv)
    return len(argv)


def refuse(argv: list[str]) -> int:
    raise Refused(f"cannot {' '.join(argv)}")


def crash(argv: list[str]) -> int:
    raise RuntimeError("a bug, not bad input")


MENU = Menu("python -m toy", {
    "echo": ("print the arguments", "tests.cli.test_menu:echo"),
    "refuse": ("fail on bad input", "tests.cli.test_menu:refuse"),
    "crash": ("fail on a bug", "tests.cli.test_menu:crash"),
}, errors=(Refused,))


def test_help_is_output_and_lists_every_command(capsys) -> None:
    assert MENU.main(["--help"]) == 0
    out, err = capsys.readouterr()
    assert err == "" and out.startswith("usage: python -m toy <command> [--help]")
    assert "  echo    print the arguments" in out and "  refuse  fail on bad input" in out


@pytest.mark.parametrize("argv, problem", [(["bogus"], "unknown command 'bogus'"), ([], "no command given")])
def test_an_unknown_or_missing_command_is_named_after_the_usage(argv, problem, capsys) -> None:
    assert MENU.main(argv) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.startswith("usage: python -m toy")
    assert err.rstrip().splitlines()[-1] == f"python -m toy: error: {problem}"


def test_a_command_gets_the_rest_of_the_line_and_its_status_is_the_exit_status(capsys) -> None:
    assert MENU.main(["echo", "a", "b"]) == 2
    assert capsys.readouterr().out == "echo a b\n"
    assert MENU.main(["echo"]) == 0


def test_declared_errors_are_one_line_and_others_propagate(capsys) -> None:
    assert MENU.main(["refuse", "this"]) == 2
    assert capsys.readouterr().err == "error: cannot this\n"
    with pytest.raises(RuntimeError, match="a bug"):
        MENU.main(["crash"])


def _menus() -> dict[str, Menu]:
    from trainer.__main__ import MENU as TRAINER
    from trainer.ddg.cli import MENU as DDG
    from trainer.student.cli import MENU as STUDENT
    from trainer.teacher.cli import MENU as TEACHER

    return {"trainer": TRAINER, "ddg": DDG, "student": STUDENT, "teacher": TEACHER}


@pytest.mark.parametrize("menu", ["trainer", "ddg", "student", "teacher"])
def test_every_command_of_every_menu_loads_and_answers_help(menu, capsys) -> None:
    """A table entry naming a moved module or a misspelt function fails here, not in a user's shell."""
    menu = _menus()[menu]
    for name, (_, target) in menu.commands.items():
        assert callable(load(target)), target
        try:
            status = menu.main([name, "--help"])  # a menu answers, an argparse command exits
        except SystemExit as stop:
            status = stop.code
        assert status in (0, None), name
        assert capsys.readouterr().out.startswith(f"usage: {menu.prog} {name}"), name


def test_command_line_records_a_module_run_as_the_user_types_it():
    argv = ["/home/u/repo/trainer/__main__.py", "student", "recipe", "--name", "a b"]
    assert command_line(argv) == "python -m trainer student recipe --name 'a b'"
    assert command_line(["/usr/bin/script.py", "--x", "1"]) == "/usr/bin/script.py --x 1"
