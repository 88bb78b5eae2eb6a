set -e
T=/work/shared/data/trees  # ../shared/data/trees
A="amrst simulate"
O=field_heldout_neighbours
mkdir -p $O
$A $T/itsme/tree_1_pc.txt --out $O/h01_tree-1-pc --seed 3001 --ground --neighbours $T/woodske/HS-SIWOOD.csv --shrubs 3 --clip-radius-m 3.5 --separation-deg 110 --distance-m 7 8
$A $T/itsme/buttressed_tree_1_pc.txt --out $O/h02_buttressed-1 --seed 3002 --ground --neighbours $T/treels/pine.laz --shrubs 4 --clip-radius-m 4.0 --separation-deg 80 --distance-m 6 9
$A $T/archi/Tree_2_point_cloud.las --out $O/h03_archi-tree-2 --seed 3003 --ground --neighbours $T/pytlidar/tree_1.las --shrubs 2 --clip-radius-m 3.0 --separation-deg 140 --distance-m 5 7
$A $T/woodske/HS-SIWOOD.csv --out $O/h04_hs-siwood --seed 3004 --ground --neighbours $T/woodske/AC-SIWOOD.csv $T/woodske/LP-SIWOOD.csv --shrubs 5 --clip-radius-m 4.5 --separation-deg 60 --distance-m 8 8
$A $T/treels/pine.laz --out $O/h05_pine-hard --seed 3005 --ground --neighbours $T/treels/pine.laz --shrubs 3 --clip-radius-m 2.5 --separation-deg 165 --distance-m 6 7 --tilt-deg 2
$A $T/pytlidar/tree_1.las --out $O/h06_palm-1-easy --seed 3006 --ground --neighbours $T/voxr/Tree_t0.asc --shrubs 3 --clip-radius-m 5.0 --separation-deg 45 --distance-m 9 6
$A $T/rtwig/cloud.txt --out $O/h07_rtwig-hard --seed 3007 --ground --neighbours $T/archi/Tree_2_point_cloud.las $T/itsme/tree_1_pc.txt --shrubs 4 --clip-radius-m 2.5 --separation-deg 170 --distance-m 5 6 --tilt-deg 2
$A $T/pytlidar/tree_1.las --out $O/h08_palm-1-hard --seed 3008 --ground --neighbours $T/treels/pine.laz $T/treels/spruce.laz --shrubs 3 --clip-radius-m 3.5 --separation-deg 150 --distance-m 7 8 --tilt-deg 2
$A $T/itsme/buttressed_tree_1_pc.txt --out $O/h09_buttressed-1-two-nb --seed 3009 --ground --neighbours $T/itsme/tree_1_pc.txt $T/pytlidar/tree_2.las --shrubs 5 --clip-radius-m 5.0 --separation-deg 120 --distance-m 9 9
$A $T/woodske/SW-SIWOOD.csv --out $O/h10_sw-siwood-near --seed 3010 --ground --neighbours $T/woodske/HS-SIWOOD.csv --shrubs 2 --clip-radius-m 3.0 --separation-deg 60 --distance-m 4 5
