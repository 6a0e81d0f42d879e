"""File formats at the bottom of the package: the sumocfg reader, the converted-scene folder, SUMO
nets as road maps. Nothing here imports the method or the simulation."""
