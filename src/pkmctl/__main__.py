from pkmctl.cli import app

app(prog_name="pkmctl")
