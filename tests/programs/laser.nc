; a grbl laser job: engrave a square with rounded corners and a cross
$H
G21 G90
X20 Y20 (the power-on motion mode is G0)
M4 S0
G1 X60 F1500 S800
G1 Y50
G2 X55 Y55 I-5 J0 S600
G1 X20
G1 Y20
M5
G0 X30 Y30
M3 S1000
G1 X50 Y45 F900
G0 X50 Y30
G1 X30 Y45
G4 P0.25
M5 S0
G0 X0 Y0
