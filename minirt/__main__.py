from minirt.cli import main

main()
