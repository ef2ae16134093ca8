"""docs/tools.md: every `ros2 ...` example line is accepted by tt's parser, and every verb of
the parser has an example."""

import argparse
import os
import shlex

import pytest
from tt_tools.ros2 import build_parser

DOC = os.path.join(os.path.dirname(__file__), '..', '..', '..', 'docs', 'tools.md')


def example_commands():
    """The ``ros2 ...`` lines of the indented example blocks (continuations joined, a shell
    pipe, redirection or comment cut off), as argument lists."""
    with open(DOC, encoding='utf-8') as f:
        lines = f.read().splitlines()
    commands, current = [], None
    for line in lines:
        text = line.strip()
        if current is not None:
            current += ' ' + text
        elif line.startswith('    ros2 ') and not text.split()[1].endswith(':'):
            current = text      # not a line a command printed ('ros2 doctor: WARNING: ...')
        else:
            continue
        if current.endswith('\\'):
            current = current[:-1]
            continue
        argv = shlex.split(current, comments=True)[1:]    # a shell comment is no argument
        for stop in ('|', '>'):
            if stop in argv:
                argv = argv[:argv.index(stop)]
        commands.append(argv)
        current = None
    return commands


def parser_verbs(parser):
    """(verb, subverb) pairs of the parser (subverb None for a verb without any)."""
    def subparsers(p):
        return next((a for a in p._actions if isinstance(a, argparse._SubParsersAction)), None)

    pairs = set()
    for verb, verb_parser in subparsers(parser).choices.items():
        sub = subparsers(verb_parser)
        pairs.update({(verb, s) for s in sub.choices} if sub else {(verb, None)})
    return pairs


COMMANDS = example_commands()


def test_the_doc_has_examples():
    assert len(COMMANDS) >= 20


@pytest.mark.parametrize('argv', COMMANDS, ids=[' '.join(a[:3]) for a in COMMANDS])
def test_the_parser_accepts_the_example(argv):
    args = build_parser().parse_args(argv)  # SystemExit (exit 2) on a bad example
    assert callable(args.func)


def test_every_verb_has_an_example():
    # A verb without subverbs (run, doctor): its first argument is no subverb.
    covered = {(a[0], None if a[0] == 'run' or len(a) < 2 or a[1].startswith('-') else a[1])
               for a in COMMANDS}
    assert parser_verbs(build_parser()) <= covered
