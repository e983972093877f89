from pkmctl.cli import main

main()
