from scantex.cli import run

run()
