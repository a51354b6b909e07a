"""Constants of the fleet's model chosen, compared or tuned while looking at the 2022 list's own results.

Cross-validation keeps the *fitted* technology out of fold; these constants were chosen by hand while
looking at errors on the same list, so they are not. ``summary.json`` (``validation.tuned_on_this_list``)
and ``report.md`` list them, each with its value, where it lives and how it was chosen (the commits that
record the choice). A test checks every value against the code, so the list cannot drift from it. Left out
on purpose: constants set before any result and never compared on the list (the friction lower bound, the
efficiency axis, the boost threshold of 75 kW/L, the rated speed, the fuel cut-off speed, the ratio spreads,
the folds' seed), and the three technology parameters themselves (fitted out of fold).
"""

from __future__ import annotations

TUNED_ON_THIS_LIST: tuple[dict, ...] = (
    {
        "name": "GEAR_RULE.min_engine_speed",
        "value": 130.0,
        "where": "src/vpsim/fleet/vehicle.py: GEAR_RULE.min_engine_speed",
        "how": "Compared 200, 140 and 130 rad/s on the first 300 vehicles' out-of-fold errors (c8af365); 130/165/200 rad/s per class later compared and not kept (743bba0).",
    },
    {
        "name": "GEAR_RULE.torque_reserve",
        "value": 0.9,
        "where": "src/vpsim/fleet/vehicle.py: GEAR_RULE.torque_reserve",
        "how": "The rule's default kept after a 0.7 and a 0.5 reserve for the CVTs were compared on the whole list and not kept (5fc1f08, 01457b7).",
    },
    {
        "name": "GEAR_RULE.full_load_engine_speed",
        "value": None,
        "where": "src/vpsim/fleet/vehicle.py: GEAR_RULE.full_load_engine_speed",
        "how": "Constant rule kept after load-dependent speeds 110->250 and 100->300 rad/s on the first 400 vehicles (5fed41d) and 300/419 rad/s for CVTs (01457b7) were compared.",
    },
    {
        "name": "MANUAL_GEAR_RULE.min_engine_speed",
        "value": 130.0,
        "where": "src/vpsim/fleet/vehicle.py: MANUAL_GEAR_RULE.min_engine_speed",
        "how": "The automatics' 130 rad/s kept for manuals in cruise after 1500 and 1750 rpm were compared on the whole list and not kept (0ce87fd).",
    },
    {
        "name": "MANUAL_UPSHIFT_MPH",
        "value": 15.0,
        "where": "src/vpsim/fleet/vehicle.py: MANUAL_UPSHIFT_MPH",
        "how": "Middle of published tables, compared on the list's out-of-fold errors with 17/24/35/41/50, 12/23/34/45/56 and 20/30/40/50/60 mph tables (a984691, a1ba716).",
    },
    {
        "name": "MANUAL_UPSHIFT_STEP_MPH",
        "value": 10.0,
        "where": "src/vpsim/fleet/vehicle.py: MANUAL_UPSHIFT_STEP_MPH",
        "how": "Step of the 15/25/35/45/55 mph table, chosen against the other published tables compared on the manuals' out-of-fold errors (a984691); replaced a 2500 rpm shift point.",
    },
    {
        "name": "MANUAL_GEAR_RULE.cruise_acceleration",
        "value": 0.1,
        "where": "src/vpsim/fleet/vehicle.py: MANUAL_GEAR_RULE.cruise_acceleration",
        "how": "Shift points apply only while accelerating, after the table used at all times and holding gear in decelerations were compared on the manuals' errors (a1ba716).",
    },
    {
        "name": "FRICTION_AXIS",
        "value": [0.1, 0.8, 1.5, 2.2, 2.9],
        "where": "src/vpsim/fleet/calibrate.py: FRICTION_AXIS",
        "how": "Friction axis raised from 0.1-1.6 to 0.1-2.9 after the boosted class's fit sat on the old 1.6 bound (c8af365).",
    },
    {
        "name": "ACCESSORY_MAX_W",
        "value": 3000.0,
        "where": "src/vpsim/fleet/calibrate.py: ACCESSORY_MAX_W",
        "how": "Accessory search 0-2000 W (4a81437), raised to 3000 W after the high-output class's fits sat on the 2 kW bound (1.7-2.0 kW over the folds).",
    },
    {
        "name": "HIGH_OUTPUT_KW_PER_L",
        "value": 100.0,
        "where": "src/vpsim/fleet/calibrate.py: HIGH_OUTPUT_KW_PER_L",
        "how": "Class threshold chosen after boosted engines above 100 kW/L showed +9.4 % bag-2 error against +0.6 % for the rest on the list (b57a62b).",
    },
    {
        "name": "BOOST_ENRICHMENT",
        "value": 0.14942528735632177,
        "where": "src/vpsim/fleet/vehicle.py: BOOST_ENRICHMENT",
        "how": "Lambda 0.87 adopted after out-of-fold runs moved US06 3.9 -> 3.5 %; 0.30 and enriching aspirated engines were compared and not kept (bac0c5f, 743bba0).",
    },
    {
        "name": "IDLE_FUEL_L_PER_H_PER_L",
        "value": 0.30283294272,
        "where": "src/vpsim/fleet/vehicle.py: IDLE_FUEL_L_PER_H_PER_L",
        "how": "Argonne figure adopted after comparing it with the preset's scaled idle out of fold on the list (bag 2 6.36 -> 6.32 %); 1.5x and 2x the preset also compared (d9adcc5).",
    },
    {
        "name": "CONVERTER_KINDS",
        "value": ["automatic", "cvt"],
        "where": "src/vpsim/fleet/vehicle.py: CONVERTER_KINDS",
        "how": "Converter for automatics and CVTs set before the run; a converter for automatics only was compared on the whole list and not kept (bbffcc4).",
    },
    {
        "name": "CONVERTER_STALL_RPM",
        "value": 2400.0,
        "where": "src/vpsim/fleet/vehicle.py: CONVERTER_STALL_RPM",
        "how": "Set before the run (middle of 2,000-2,800 rpm); a 2,000 rpm stall was then compared on the whole list and not kept (bbffcc4).",
    },
    {
        "name": "LOCKUP_MIN_GEAR",
        "value": 2,
        "where": "src/vpsim/fleet/vehicle.py: LOCKUP_MIN_GEAR",
        "how": "Set before the run; lock-up from gear 3 above 40 km/h was compared on the whole list and not kept (743bba0).",
    },
    {
        "name": "LOCKUP_MIN_SPEED_KMH",
        "value": 25.0,
        "where": "src/vpsim/fleet/vehicle.py: LOCKUP_MIN_SPEED_KMH",
        "how": "Set before the run; 15 and 40 km/h (bbffcc4), 40 km/h from gear 3 (743bba0) and 12 km/h for CVTs (1f37669) were compared on the whole list and not kept.",
    },
    {
        "name": "CVT_RATIO_STEP",
        "value": 0.02,
        "where": "src/vpsim/fleet/vehicle.py: CVT_RATIO_STEP",
        "how": "2 % grid adopted on the list's out-of-fold errors (01457b7); a finer step was checked to move no fleet figure; 16 vs 8 fixed ratios compared earlier (743bba0, 5fc1f08).",
    },
    {
        "name": "TRANSMISSION_EFFICIENCY",
        "value": 0.92,
        "where": "src/vpsim/fleet/vehicle.py: TRANSMISSION_EFFICIENCY",
        "how": "Kept after 0.96 (743bba0), 0.88 for all-wheel drive (ce8465f) and 0.95/0.97 with a spin-loss stand-in (01e4810) were compared on the list.",
    },
    {
        "name": "HOT_TOWN_HYBRID_RATIO",
        "value": 0.86,
        "where": "src/vpsim/fleet/epa.py: HOT_TOWN_HYBRID_RATIO",
        "how": "Row filter on measured mpg: set just above the 0.44-0.85 bag-2/highway ratio of the list's conventional cars, after the 2022 run still held hybrids (b3bbcb7).",
    },
    {
        "name": "HWY_EFFICIENCY_HYBRID",
        "value": 0.35,
        "where": "src/vpsim/fleet/epa.py: HWY_EFFICIENCY_HYBRID",
        "how": "Row filter on measured highway mpg: set between the list's conventional maximum (0.34) and the Hyundai Ioniq hybrid's 0.37 that slipped through (e4790f7).",
    },
    {
        "name": "HYBRID_NAME.pattern",
        "value": "hybrid|\\b[fp]?hev\\b|\\b\\d{3}h\\b",
        "where": "src/vpsim/fleet/epa.py: HYBRID_NAME.pattern",
        "how": "HEV and 300h names added after the 2022 run still held hybrids, such as the Lexus ES 300h at 97 mpg in bag 2 (b3bbcb7).",
    },
    {
        "name": "MILD_HYBRID_NAME.pattern",
        "value": "\\bmhev\\b|mild hybrid",
        "where": "src/vpsim/fleet/epa.py: MILD_HYBRID_NAME.pattern",
        "how": "Mild-hybrid exclusion (with the 4-bag FTP rule) added after the bag-2 error's negative tail proved to be 48 V cars, -10 % town when kept (d8064bc); since vpsim.fleet.mhev the rule routes them to the mild-hybrid model instead.",
    },
    {
        "name": "mhev.EFFICIENCY_AXIS",
        "value": [0.34, 0.38, 0.42, 0.46, 0.5, 0.54],
        "where": "src/vpsim/fleet/mhev.py: EFFICIENCY_AXIS",
        "how": "Set to 0.30-0.50 first; widened to the full hybrids' 0.34-0.54 after the first out-of-fold fit (the list's first 20 mild hybrids, --limit 20) sat on 0.50 in every fold (b60030c).",
    },
    {
        "name": "mhev.TECH_PARAMS",
        "value": ["engine.thermal_efficiency", "electric.accessory_power", "engine.friction_coefficient"],
        "where": "src/vpsim/fleet/mhev.py: TECH_PARAMS",
        "how": "The mild hybrids' engine friction was the preset's (hofman2011, 1.34); the conventional fit per engine class (aspirated 0.6, boosted 0.95, high-output 0.4) was compared on all 89 mild hybrids out of fold (bag 2 / bag 3 / HWY / US06 median |error| 8.8 / 4.2 / 5.7 / 10.0 % against 7.2 / 4.3 / 5.8 / 9.6 %) and not kept; then fixed 0.1 (6.4 / 4.0 / 5.7 / 7.8 %) and 0.7 (8.1 / 3.7 / 4.9 / 10.4 %) were compared (benchmarks/mhev_oof.py), and the friction fitted out of fold per class on the conventional classes' axis 0.1-2.9 was adopted: 6.4 / 4.0 / 5.5 / 7.8 %, mhev_p0 on the 0.1 bound in every fold.",
    },
    {
        "name": "mhev.CONVERTER",
        "value": False,
        "where": "src/vpsim/fleet/mhev.py: CONVERTER",
        "how": "The mild hybrids' torque-converter automatics (codes A, SA) given their converter (the crank its pump below lock-up, no recuperation there) were compared out of fold after bag 2's errors were looked into (benchmarks/mhev_oof.py --converter): bag 2 / bag 3 / HWY / US06 median |error| 6.4 / 4.0 / 5.5 / 7.8 % with the clutch against 6.8 / 3.6 / 5.0 / 9.0 % with the converter; the fitted accessory load stayed at 2.2-2.7 kW. Not kept (the clutch stays); the model has the converter (vpsim.model.hybrid.p2_interval).",
    },
    {
        "name": "mhev.ASSIST_SHARE",
        "value": {"audi48": 0.0, "audi_a3": 0.75, "audi12": 0.2},
        "where": "src/vpsim/fleet/mhev.py: ASSIST_SHARE",
        "how": "The makers' published assist looked up (Audi's A8 and A3 pages, the Volkswagen Group's MHEV description, a 2015 article on Audi's 12 V system) after the 2026-12-07 run had Audi's 6- and 8-cylinder 48 V cars +10.5 / +12.8 / +14.0 % (bag 2 / bag 3 / US06) too frugal; until then every system assisted with its whole machine. With AUDI_12V_MACHINE_KW, out of fold (benchmarks/mhev_oof.py): bag 2 / bag 3 / HWY / US06 median |error| 6.7 / 4.0 / 5.2 / 9.9 % before, 5.2 / 4.6 / 5.7 / 7.3 % after; the 48 V part alone (the 12 V system as before) 5.9 / 3.9 / 5.3 / 7.4 %. Both parts kept as the published specifications, the 12 V part although it moved bag 3 and HWY the wrong way.",
    },
    {
        "name": "mhev.AUDI_12V_MACHINE_KW",
        "value": 5.0,
        "where": "src/vpsim/fleet/mhev.py: AUDI_12V_MACHINE_KW",
        "how": "Audi's 12 V system's published recuperation power (at most 5 kW, 1 kW assist: a 2015 article on the system) in place of 3 kW estimated from a 12 V machine's current, looked up with ASSIST_SHARE (its figures there).",
    },
    {
        "name": "PLAUSIBLE['mpg']",
        "value": [5.0, 150.0],
        "where": "src/vpsim/fleet/epa.py: PLAUSIBLE['mpg']",
        "how": "Filters test values by their measured outcome: a measured mpg outside 5-150 is dropped; set when the reader was written (8f9fbf8), no comparison recorded.",
    },
    {
        "name": "FORWARD_DRIVER",
        "value": "2",
        "where": "src/vpsim/fleet/run.py: FORWARD_DRIVER",
        "how": "The stiffer preset driver, chosen because driver 1 left the +-2 km/h band for 75-115 s of bag 2 in every fleet run (fa63428).",
    },
    {
        "name": "scaled_drivers",
        "value": "K_p and K_i times engine.max_command over the preset's",
        "where": "src/vpsim/fleet/vehicle.py: scaled_drivers",
        "how": "Gains scaled with A_max after the forward fleet's band misses (e70dc76), then with the pedal's range after boosted cars' US06 band misses (1421f85).",
    },
    {
        "name": "city_mpg_at_least_highway",
        "value": "a record whose city (FTP) mpg is at least its highway mpg is excluded as a hybrid",
        "where": "src/vpsim/fleet/epa.py: _classify",
        "how": "Row filter on the measured outcome, written with the reader (8f9fbf8) before any fleet result; listed because it filters rows by what they measured.",
    },
    {
        "name": "model_shares_exclusion",
        "value": "every test vehicle of a make and model excluded when one of them is a plug-in or hybrid",
        "where": "src/vpsim/fleet/epa.py: read_test_car_list",
        "how": "Added after the RAV4 Prime's gasoline-only test vehicle ran as a conventional car at -25 % on US06 (cfd8bc1); 12 more vehicles excluded.",
    },
    {
        "name": "KWH_PER_100MI_BELOW",
        "value": 60.0,
        "where": "src/vpsim/fleet/peer_bev.py: KWH_PER_100MI_BELOW",
        "how": "Unit rule on measured values: set after seeing that 16 EV records of the list under FE_UNIT MPG hold 17-38 (kWh/100 mi) while no 2022 EV tests below 60 MPGe (54b25b6); no comparison of errors.",
    },
    {
        "name": "MPGE_RANGE",
        "value": [40.0, 300.0],
        "where": "src/vpsim/fleet/ev.py: MPGE_RANGE",
        "how": "Filters EV tests by their measured outcome (the list's 82-191 MPGe well inside); set when the EV reader was written, before any vpsim EV result; no comparison recorded.",
    },
    {
        "name": "machine_kind",
        "value": "the Audi e-tron, e-tron S and e-tron Sportback (every traction machine an induction machine, by Audi's specification) run as kind induction in a technology class bev_induction of their own",
        "where": "src/vpsim/fleet/ev.py: machine_kind",
        "how": "Class split added after these Audis showed the 2022 EVs' largest errors (UDDS +34..+44 %); the machine kind is the maker's, not fitted; out of fold the split moved UDDS median |error| 10.0 -> 8.8 %, highway 5.8 -> 5.2 %.",
    },
    {
        "name": "ev_class",
        "value": "BEV technology classes: induction models (machine_kind), then the EESM models (bev_eesm), then a record with 2+ gears (bev_two_speed), then Drive System Code A/4/P (bev_awd), else bev",
        "where": "src/vpsim/fleet/ev.py: ev_class",
        "how": "Split by record fields added after the single class's worst rows proved to be the two-speed Taycans and e-tron GTs; out of fold (with the induction class and the loss axis below) UDDS median/p90 |error| 7.3/20.9 -> 4.8/14.2 % with the two-speed class, -> 4.9/12.5 % adding the AWD class; highway 3.7/9.7 -> 2.9/7.1 -> 2.5/7.3 %.",
    },
    {
        "name": "eesm_class",
        "value": "the BMW i4 and iX (fifth-generation eDrive: electrically excited synchronous machines, by BMW's specification) in a technology class bev_eesm of their own",
        "where": "src/vpsim/fleet/ev.py: ev_class",
        "how": "Class split added after the BMW i4 and iX showed the largest UDDS errors left but the Bolt EV's (+10 to +15 %, UDDS/highway MPGe ratio 1.01-1.02 against 1.1-1.35 for the other single-reduction cars); the machine type is the maker's, not fitted. Out of fold by family UDDS median/p90 |error| 4.9/12.5 -> 4.2/10.8 %, highway 2.5/7.3 -> 2.5/7.5 %; one manufacturer held out (the BMWs then fall back to all classes) UDDS 5.6/15.1 -> 5.2/15.5 %, highway 3.4/11.8 -> 2.8/12.6 %. FASTSim's calibration on the same classes gained more on UDDS (median/p90 |error| 5.1/13.6 -> 3.7/12.7 %, now below vpsim's 4.2), highway 3.7/8.4 -> 4.4/8.3 %. Also compared and not kept: the AWD records as two machines sharing the rated power with the second decoupled at part load (emulated as the no-load loss terms halved, copper doubled; with the loss model's scaling, two machines sharing the torque lose what one machine of the summed rating does): UDDS 4.8/12.5 %, highway 2.5/7.3 %.",
    },
    {
        "name": "LOSS_SCALE_AXIS",
        "value": [0.01, 0.03, 0.06, 0.1, 0.15, 0.2, 0.3, 0.4, 0.55, 0.7, 0.9, 1.1, 1.3, 1.5],
        "where": "src/vpsim/fleet/ev.py: LOSS_SCALE_AXIS",
        "how": "Lower end moved from 0.1 to 0.01 after the bev class's fit sat on 0.1 in every fold; the one class (with the induction class beside it) then took 0.01-0.05 with 1.05-1.25 kW accessory power; out of fold UDDS median |error| 8.8 -> 7.3 %, highway 5.2 -> 3.7 %.",
    },
    {
        "name": "MIN_POWER_W_PER_KG",
        "value": 30.0,
        "where": "src/vpsim/fleet/ev.py: MIN_POWER_W_PER_KG",
        "how": "Set after reading the Kona Electric's and Niro EV's 37/38 hp (15 W/kg) in the list's fields, before any vpsim EV result; those two also fall below the general 40 hp bound.",
    },
    {
        "name": "hev_class",
        "value": "hybrid technology classes: the layout (hev_split, hev_p2), a P2 with a torque-converter automatic (transmission code A or SA) in a class hev_p2_converter of its own",
        "where": "src/vpsim/fleet/hev.py: hev_class",
        "how": "Split added after the single P2 class's out-of-fold errors were seen: the trucks' hot UDDS +24..+48 % (the Explorer, F-150, Police Interceptor and Tundra, all longitudinal 10-speed converter automatics) beside the Hyundai/Kia 6-speeds' HWY -14..-20 %; the classes split by a record field, the gearbox code.",
    },
    {
        "name": "p2_converter",
        "value": "a P2 with a torque-converter automatic (codes A, SA: Ford's 10-speed modular hybrid transmission, Toyota's i-FORCE MAX 10-speed) keeps its converter between machine and gearbox: the conventional automatics' converter and lock-up (vpsim.fleet.vehicle.converter_fields, unchanged)",
        "where": "src/vpsim/fleet/hev.py: hev_parameters",
        "how": "Built after the converter class's fits sat on both bounds of the grid (0.34, 1.5 kW) with hot UDDS +12.6 % and highway -10.3 %; the layout is the makers' and the converter's constants are the conventional automatics' (set before, not changed here). Out of fold by family (benchmarks/hev_out_of_fold.py) the class's hot UDDS median/p90 |error| 12.6/21.4 -> 4.8/11.5 %, highway 10.3/14.7 -> 7.4/11.5 %; the Hyundai/Kia P2 bit for bit unchanged.",
    },
    {
        "name": "P2_MACHINE_SCALE",
        "value": [1.0, 1.4],
        "where": "src/vpsim/fleet/hev.py: P2_MACHINE_SCALE",
        "how": "The P2 machine's scale with test weight capped at 1.4 x the preset's 32 kW after a first look at the preset-technology errors (the trucks got 57-64 kW where their makers list 35-36 kW); the cap is from the makers' 32-47 kW, it moved the trucks' hot-UDDS errors by 1-3 points only.",
    },
    {
        "name": "SPLIT_CODES",
        "value": ["CVT", "SCV"],
        "where": "src/vpsim/fleet/hev.py: SPLIT_CODES",
        "how": "SCV (the selectable CVT) added after the reader's first pass excluded the RAV4 Hybrid AWD (19-AA2H) for its code; read from the list's fields before any vpsim result for that car.",
    },
    {
        "name": "COMPOSITE_TOLERANCE",
        "value": 0.03,
        "where": "src/vpsim/fleet/hev.py: COMPOSITE_TOLERANCE",
        "how": "Filters hybrid FTP rows by their measured bags (the 0.43/0.57 composite of the bags against RND_ADJ_FE): set from the Corolla Hybrid's and the Explorer's rows (0.5 % and 0.2 %), before any vpsim hybrid result; it drops one Elantra Hybrid FTP (62.7 against 68.3 mpg).",
    },
    {
        "name": "MACHINE_LOSS_SCALE",
        "value": 0.15,
        "where": "src/vpsim/fleet/hev.py: MACHINE_LOSS_SCALE",
        "how": "The hybrids' machine losses at the level the 2022 single-machine PM EVs fit out of fold (class bev: 0.14-0.15 in every fold), adopted after the hybrids' highway bias was traced to the electric path (MG2's spin loss about 3 kW at 95 km/h on a Camry at the loss model's own level); before that, 1, 0.3 and 0.1 were compared on the hybrids' in-sample fits (highway median -6.0/-7.2/-5.7 % for the splits with the old pack rule, -3.8/-0.4 % at 1/0.3 with one string); the value is the EVs', not chosen among these.",
    },
    {
        "name": "ev.TECH_PARAMS",
        "value": ["machine.loss_scale", "electric.accessory_power", "transmission.efficiency"],
        "where": "src/vpsim/fleet/ev.py: TECH_PARAMS",
        "how": "The EV classes fitted the machine's loss level and the accessories only, the loss level on its 0.01 bound in most folds (a lossless machine, its regeneration too); after the UDDS residuals were seen to grow with test weight (Spearman 0.52 on the UDDS/highway ratio), two fixed drive efficiencies were run out of fold (benchmarks/ev_udds_variants.py drive_eff_0.93 drive_eff_0.90: UDDS / HWY median |error| 4.22 / 2.51 -> 3.86 / 2.85 and 3.61 / 3.30 %) and the drive efficiency became the third parameter fitted per class out of fold, nodes 0.86/0.91/0.96/1.0 set before its first run: 4.22 / 2.51 -> 3.94 / 2.65 % (p90 10.81 / 7.47 -> 10.19 / 7.00); the fixed values were not adopted.",
    },
    {
        "name": "hev.TECH_PARAMS",
        "value": ["engine.thermal_efficiency", "electric.accessory_power", "machine.loss_scale"],
        "where": "src/vpsim/fleet/hev.py: TECH_PARAMS",
        "how": "The full hybrids' machine-loss level was the EVs' fixed 0.15 (MACHINE_LOSS_SCALE) until one other level, 2, was tried on the P2s out of fold after their errors were looked into (benchmarks/hev_out_of_fold.py --set machine.loss_scale=2 --layout hev_p2: P2s hot UDDS / HWY / US06 median |error| 6.2 / 5.8 / 4.6 -> 4.4 / 2.4 / 3.2 %); it is since fitted per class out of fold as the third technology parameter, in the EV class's search range 0.01-1.5 (set before any hybrid result; 2 is outside it), nodes 0.01/0.15/0.5/1/1.5: all full hybrids 3.74 / 2.72 / 3.09 -> 2.77 / 2.76 / 2.91 % (p90 10.0 / 10.5 / 5.9 -> 10.1 / 7.8 / 5.9), the converter trucks on the 1.5 bound in every fold, the Hyundai/Kia P2 on the 0.01 bound in four of five (0.03 in the fifth). A further split of the Hyundai/Kia P2s by boost was measured the same way (2.77 / 2.93 / 2.31 %) and not kept.",
    },
    {
        "name": "battery_strings",
        "value": "a hybrid's pack is its preset's one string: 1.31 kWh for a power split, 1.54 kWh for a P2",
        "where": "src/vpsim/fleet/hev.py: battery_strings",
        "how": "The split's pack had been sized to MG2's rating (3-7 strings, 3.9-9.2 kWh against the makers' 0.75-1.9 kWh); found while tracing the splits' highway errors, the rule set from the makers' pack sizes; in-sample it moved the splits' highway median -6.0 -> -3.8 % (loss model at its own level). The P2's pack (two strings, 3.1 kWh, for every P2 by the machine's power at the cell's discharge limit, the Ioniq preset's own car included) set to the preset's one string after the P2s' errors were looked into, from the makers' 1.5-1.9 kWh P2 packs; out of fold (with the converter) hev_p2 hot UDDS median/p90 |error| 9.1/17.8 -> 7.6/15.8 %, highway 5.2/12.0 -> 4.9/10.9 %, US06 5.2/11.8 -> 4.6/9.1 %; hev_p2_converter hot UDDS 4.8/11.5 -> 4.9/12.8 %, highway 7.4/11.5 -> 7.7/10.7 %; both classes' accessory power then on or next to its 1.5 kW bound.",
    },
)
