from racer.cli import main

main()
