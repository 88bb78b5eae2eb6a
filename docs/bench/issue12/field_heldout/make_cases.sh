set -e
T=/work/shared/data/trees  # ../shared/data/trees
A="amrst simulate"
O=field_heldout
mkdir -p $O
$A $T/itsme/buttressed_tree_1_pc.txt --out $O/s1_buttressed-1-normal --seed 4001 --ground --neighbours $T/woodske/SW-SIWOOD.csv --shrubs 3 --clip-radius-m 4.0 --separation-deg 80 --distance-m 6 9
$A $T/woodske/SW-SIWOOD.csv --out $O/s2_sw-siwood-normal --seed 4002 --ground --neighbours $T/woodske/AC-SIWOOD.csv --shrubs 4 --clip-radius-m 3.0 --separation-deg 120 --distance-m 5 7
$A $T/woodske/AC-SIWOOD.csv --out $O/s3_ac-siwood-easy --seed 4003 --ground --neighbours $T/itsme/buttressed_tree_1_pc.txt --shrubs 2 --clip-radius-m 4.5 --separation-deg 50 --distance-m 8 8
$A $T/rtwig/cloud.txt --out $O/s4_rtwig-hard --seed 4004 --ground --neighbours $T/woodske/SW-SIWOOD.csv $T/woodske/AC-SIWOOD.csv --shrubs 4 --clip-radius-m 2.5 --separation-deg 170 --distance-m 5 6 --tilt-deg 2
$A $T/itsme/buttressed_tree_1_pc.txt --out $O/s5_buttressed-1-hard --seed 4005 --ground --neighbours $T/woodske/AC-SIWOOD.csv $T/rtwig/cloud.txt --shrubs 5 --clip-radius-m 5.0 --separation-deg 160 --distance-m 9 8 --tilt-deg 2
$A $T/woodske/SW-SIWOOD.csv --out $O/s6_sw-siwood-easy --seed 4006 --ground --neighbours $T/itsme/buttressed_tree_1_pc.txt --shrubs 3 --clip-radius-m 3.5 --separation-deg 45 --distance-m 4 6
$A $T/woodske/AC-SIWOOD.csv --out $O/s7_ac-siwood-hard --seed 4007 --ground --neighbours $T/woodske/SW-SIWOOD.csv $T/rtwig/cloud.txt --shrubs 3 --clip-radius-m 3.0 --separation-deg 175 --distance-m 6 8 --tilt-deg 2
$A $T/woodske/SW-SIWOOD.csv --out $O/s8_sw-siwood-hard --seed 4008 --ground --neighbours $T/woodske/AC-SIWOOD.csv $T/itsme/buttressed_tree_1_pc.txt --shrubs 4 --clip-radius-m 4.0 --separation-deg 155 --distance-m 9 5 --tilt-deg 2
$A $T/itsme/buttressed_tree_1_pc.txt --out $O/s9_buttressed-1-two-nb --seed 4009 --ground --neighbours $T/woodske/SW-SIWOOD.csv $T/woodske/AC-SIWOOD.csv --shrubs 3 --clip-radius-m 2.5 --separation-deg 100 --distance-m 7 7
$A $T/rtwig/cloud.txt --out $O/s10_rtwig-normal --seed 4010 --ground --neighbours $T/itsme/buttressed_tree_1_pc.txt --shrubs 5 --clip-radius-m 3.5 --separation-deg 130 --distance-m 4 9
