"""The real programs of bench/filter_corpus.py: where each comes from and which arm runs it.

Each :class:`Program` is a set of files filtered together (a RAPID task, a KRL program with
its ``.dat`` and ``$config.dat``, one Fanuc ``.LS`` with its backup's frames, one URScript),
named by repository, commit and path. Nothing here is a copy: ``fetch`` extracts the files
from a clone into a directory outside the repository.

``arm``: a built-in library name (``cablecal robots``), or ``mada:PATH`` for a KUKA arm
the library has not, whose model is built from that backup's own ``$machine.dat`` by
bench/robots_kuka.py's rule. ``arm_source`` says where the arm comes from ("stated": the
repository names it; "assumed": a lab cell whose arm the files do not name).
``frames``: a Fanuc backup's ``SYSFRAME.VA``, made into ``--frames`` (``[uframe.N]``,
``[utool.N]`` of group 1).
"""

from __future__ import annotations

from dataclasses import dataclass, replace


@dataclass(frozen=True)
class Program:
    id: str
    language: str  # rapid, krl, fanuc, urscript
    repo: str
    commit: str
    paths: tuple[str, ...]
    arm: str
    arm_source: str
    what: str
    frames: str = ""
    #: ``--frames`` text when the repository has no SYSFRAME.VA (an assumption, said so).
    frames_toml: str = ""
    #: False for a file the controller would not load either (then (a) expects exit 2).
    valid: bool = True
    #: A what-if: the model file says the controller drives no external axis
    #: (``[controller] external_axes = 0``, where the code knows it).
    no_external_axes: bool = False
    #: The program whose fetched files a what-if reuses (its directory under CORPUS).
    files_of: str = ""


_TP = ("TPHugo/TimovyProjekt", "e6e904851a265e9226b45991e0407a59c52a3666")
_ECL = ("ebruun/ECL_robotic_cell", "b515d32356124fc4e333fa53a0db4052c7cdcc98")
_TMC = ("dkaynarc/tmc", "aa948a3130959f7551ff9910cf7574f81fbaaaec")
_MC = ("mcoffman1/industrial_robotics_shared", "20c629b492a499b7055c25f498a514b8d7412471")
_HB = ("harshbhatt99/abb_robotstudio_projects", "eaaceac37c7cc23826369f8d151ee96b20ff2983")
_FO = ("fore1806/Proyecto-Rob", "c99c94eec0f434ca85782741a09162e9818cb934")
_ERR = ("Aleynikovich/errekaSmartPal", "b1bf3f7a6b27a2d14ad41040c4e0e1cdeed39958")
_ZIN = ("Aleynikovich/Zinkerreka", "415730cd7dac90192520f5c1b54b3d51d3f4a435")
_CHM = ("HugoDanielson/ChinaMilling", "04c963fece86c21dd117b7228a9f8dfd7158cfa2")
_KRC4 = ("khrzysio/KRC4_test", "e8042ab5a504678183de1a983b8cf0e6c7b576c6")
_TFG = ("luciagumbau228/TFG", "b840b128b3555da435b4f065513155c678fb7a91")
_VASC = ("JuniorNatalin/VASC", "02f99794238f333324a4c319c7bfa7bde4e3fd9b")
_PH = "pharmbio/robotlab"
_WELD = ("Creearc/welding_project", "a1517840dc5596775124078c32cdcd4ef56ebe06")
#: The welding job's UF 6 and UT 5 are not in its repository: a work frame 800 mm in front
#: of axis 1 and a torch 300 mm out along the flange, pointing back at it (the job's W P R
#: of 0 then has the flange facing down). Assumed, not the cell's.
WELD_FRAMES = """[uframe.6]
xyz_mm = [800.0, 0.0, 0.0]
wpr_deg = [0.0, 0.0, 0.0]

[utool.5]
xyz_mm = [0.0, 0.0, 300.0]
wpr_deg = [0.0, 180.0, 0.0]
"""


def _weld(pid: str, path: str) -> Program:
    return Program(
        pid,
        "fanuc",
        _WELD[0],
        _WELD[1],
        (path,),
        "fanuc-m10ia",
        "stated (the repo's saved controller page: M-10iA); frames assumed",
        "OLP welding job (GP2 positioner)",
        frames_toml=WELD_FRAMES,
    )


def _rapid(
    pid: str, src: tuple[str, str], paths: tuple[str, ...], arm: str, how: str, what: str
) -> Program:
    return Program(pid, "rapid", src[0], src[1], paths, arm, how, what)


def _krl(pid: str, src: tuple[str, str], root: str, prog: str, arm: str, how: str) -> Program:
    paths = (
        f"{root}/Program/{prog}.src",
        f"{root}/Program/{prog}.dat",
        f"{root}/System/$config.dat",
    )
    return Program(pid, "krl", src[0], src[1], paths, arm, how, "controller backup")


def _ls(pid: str, backup: str, files: tuple[str, ...]) -> Program:
    return Program(
        pid,
        "fanuc",
        _VASC[0],
        _VASC[1],
        tuple(f"{backup}/{f}" for f in files),
        "fanuc-r2000ib-210f",
        "stated (VERSION.VA)",
        "controller backup",
        frames=f"{backup.removesuffix('/GERMAN').removesuffix('/ENGLISH')}/SYSFRAME.VA",
    )


_ST = "Stavbar"
_L1 = "KJLTVX/Backups/24.06.2024/LTVR"
_L0 = "KJLTVX/Backups/15.07.2024/LTVL"
_BV = "BVTU/Backups/07.10.24/KJBVTU211160R01"
_ECLB = "_controller_backups/4600-COMPAS_RRC_BACKUP_legacy/HOME"

PROGRAMS: tuple[Program, ...] = (
    # RAPID: OLP (Grasshopper), RobotStudio stations, controller backups
    _rapid(
        "rapid-tp-piramida",
        _TP,
        (f"{_ST}/Piramida/MainModule.mod",),
        "abb-irb120",
        "assumed",
        "OLP (Grasshopper TACO)",
    ),
    _rapid(
        "rapid-tp-coloseum",
        _TP,
        (f"{_ST}/RTVS/coloseum/MainModule.mod",),
        "abb-irb120",
        "assumed",
        "OLP (Grasshopper TACO)",
    ),
    _rapid(
        "rapid-tp-stenar",
        _TP,
        (f"{_ST}/RTVS/stenaR/MainModule.mod",),
        "abb-irb120",
        "assumed",
        "OLP (Grasshopper TACO)",
    ),
    _rapid(
        "rapid-tp-grasshopper",
        _TP,
        ("Grasshopper/T_ROB1.mod",),
        "abb-irb120",
        "assumed",
        "OLP (Grasshopper TACO)",
    ),
    _rapid(
        "rapid-ecl-grey",
        _ECL,
        (f"{_ECLB}/Grey/Grey_T_ROB1.mod",),
        "abb-irb4600-60-205",
        "stated (backup name)",
        "controller backup (track)",
    ),
    replace(
        _rapid(
            "rapid-ecl-sheetforming",
            _ECL,
            (f"{_ECLB}/SheetformingTODAY/SheetformingTODAY_T_ROB1.mod",),
            "abb-irb4600-60-205",
            "stated (backup name)",
            "controller backup (track); moves after ENDMODULE: not loadable",
        ),
        valid=False,
    ),
    _rapid(
        "rapid-tmc-modfiles",
        _TMC,
        tuple(
            f"src/cluster/Tmc/Robotics/bin/Debug/modFiles/{f}.mod"
            for f in (
                "Grab_Tray_1",
                "Grab_Tray_2",
                "GetMagazine",
                "ReturnMagazine",
                "Slot_0",
                "PlaceTablet",
            )
        ),
        "abb-irb120",
        "assumed",
        "RobotStudio Path modules",
    ),
    _rapid(
        "rapid-mc-example",
        _MC,
        ("ABB/Example Scripts/AA_example_script.mod",),
        "abb-irb120",
        "stated (IRB120 in repo)",
        "hand-written",
    ),
    _rapid(
        "rapid-mc-circle",
        _MC,
        ("ABB/Example Scripts/circle_offset.mod",),
        "abb-irb120",
        "stated (IRB120 in repo)",
        "hand-written",
    ),
    _rapid(
        "rapid-mc-cognex",
        _MC,
        ("ABB/ABB Cognex/inst_camera_module.mod",),
        "abb-irb120",
        "stated (IRB120 in repo)",
        "hand-written",
    ),
    _rapid(
        "rapid-wsierrad-t1",
        ("wsierrad/Lab5_Robotica", "b737ac69a92508feb12ed2b8587641083ccdd89c"),
        ("Module1_2_Tarea1.mod",),
        "abb-irb140",
        "assumed (UNAL lab IRB 140)",
        "RobotStudio station",
    ),
    _rapid(
        "rapid-jplazag-t1",
        ("jplazag/Lab5_robotica", "eadf75ad334a3b9955f123362d57cb1b353770c5"),
        ("Module_Tarea1.mod",),
        "abb-irb140",
        "assumed (UNAL lab IRB 140)",
        "RobotStudio station",
    ),
    _rapid(
        "rapid-egm-irb120",
        ("rparak/ABB_EGM_Python", "aac0bf1456b156b70c8dbcee7c57bc424597b13e"),
        ("ABB_RobotStudio/ABB_IRB_120/T_ROB_1/Module1.mod",),
        "abb-irb120",
        "stated (folder)",
        "RobotStudio station",
    ),
    _rapid(
        "rapid-hb-automation",
        _HB,
        ("automation-sequence/Module1.mod", "automation-sequence/CalibData.mod"),
        "abb-irb120",
        "stated (README)",
        "RobotStudio station",
    ),
    _rapid(
        "rapid-hb-pathtracing",
        _HB,
        ("path-tracing/Module1.mod", "path-tracing/CalibData.mod"),
        "abb-irb120",
        "stated (README)",
        "RobotStudio station",
    ),
    _rapid(
        "rapid-fore-lab",
        _FO,
        ("RAPID/ProyectoLab/Module1.mod", "RAPID/ProyectoLab/CalibData.mod"),
        "abb-irb140",
        "stated (IRB140 in repo)",
        "RobotStudio station",
    ),
    _rapid(
        "rapid-fore-sim",
        _FO,
        ("RAPID/Simulacion/Module1.mod", "RAPID/Simulacion/CalibData.mod"),
        "abb-irb140",
        "stated (IRB140 in repo)",
        "RobotStudio station",
    ),
    _rapid(
        "rapid-cuestas",
        ("ChrisCuestas/Unal-Rob-Project", "ad3ce96f6389a0785f74f39df88a043f56f3486f"),
        ("RAPID/Module1.mod", "RAPID/CalibData.mod"),
        "abb-irb140",
        "assumed (UNAL lab IRB 140)",
        "RobotStudio station",
    ),
    _rapid(
        "rapid-mora",
        ("mora200217/proyecto-rob", "f43c7be38c1492d5c807365c0ee33a58ae0a3ae4"),
        ("Rapid_proyecto/Module1.mod", "Rapid_proyecto/CalibData.mod"),
        "abb-irb140",
        "stated (IRB140 in repo)",
        "RobotStudio station",
    ),
    # KRL: controller backups with $config.dat
    _krl(
        "krl-erreka-m72x860",
        _ERR,
        "KRC/R1",
        "Programas2Tornos/m72x860",
        "mada:KRC/R1/Mada/$machine.dat",
        "its $machine.dat (KR 125)",
    ),
    _krl(
        "krl-erreka-paletizado860",
        _ERR,
        "KRC/R1",
        "Programas2Tornos/paletizado860",
        "mada:KRC/R1/Mada/$machine.dat",
        "its $machine.dat (KR 125)",
    ),
    _krl(
        "krl-erreka-cinta",
        _ERR,
        "KRC/R1",
        "CINTA/cinta",
        "mada:KRC/R1/Mada/$machine.dat",
        "its $machine.dat (KR 125)",
    ),
    _krl(
        "krl-erreka-patron",
        _ERR,
        "KRC/R1",
        "Programas2Tornos/patron",
        "mada:KRC/R1/Mada/$machine.dat",
        "its $machine.dat (KR 125)",
    ),
    _krl(
        "krl-zin-pickconveyor",
        _ZIN,
        "KRC/R1",
        "Work/C1_pickConveyorBP",
        "kuka-kr210-r2700-prime",
        "its $machine.dat",
    ),
    _krl(
        "krl-zin-teaching",
        _ZIN,
        "KRC/R1",
        "Service/C252_TeachingPointsC2",
        "kuka-kr210-r2700-prime",
        "its $machine.dat",
    ),
    _krl(
        "krl-zin-ciclo",
        _ZIN,
        "KRC/R1",
        "Work/C2_CicloCompleto",
        "kuka-kr210-r2700-prime",
        "its $machine.dat",
    ),
    _krl(
        "krl-chm-job1side1",
        _CHM,
        "KRC/R1",
        "KukaMiling/Jobs/St1/St1_Job1_Side1",
        "kuka-kr210-r2700-2",
        "its $machine.dat",
    ),
    _krl(
        "krl-chm-testmill",
        _CHM,
        "KRC/R1",
        "KukaMiling/Jobs/St1/St1_Test_Mill",
        "kuka-kr210-r2700-2",
        "its $machine.dat",
    ),
    _krl(
        "krl-naqiu-honai",
        ("Naqiu06/KUKA-Robotics", "66cb2cd074c801bf5b5f12a127d944412192c607"),
        "KRC/R1",
        "honai",
        "kuka-kr6-r900",
        "its $machine.dat",
    ),
    _krl(
        "krl-krc4-millframe",
        _KRC4,
        "R1",
        "CELL/Frame/Mill_FrameAut3",
        "mada:R1/Mada/$machine.dat",
        "its $machine.dat (KR 120 R2700 extra)",
    ),
    _krl(
        "krl-krc4-millleaf",
        _KRC4,
        "R1",
        "CELL/Leaf/Mill_LeafAut3",
        "mada:R1/Mada/$machine.dat",
        "its $machine.dat (KR 120 R2700 extra)",
    ),
    _krl(
        "krl-tfg-main",
        _TFG,
        "R1",
        "Main",
        "mada:R1/Mada/$machine.dat",
        "its $machine.dat (KR 140 R3200)",
    ),
    _krl(
        "krl-tfg-dejar",
        _TFG,
        "R1",
        "Dejar",
        "mada:R1/Mada/$machine.dat",
        "its $machine.dat (KR 140 R3200)",
    ),
    # Fanuc: controller backups (R-2000iB/210F) with their SYSFRAME.VA
    _ls("ls-ltvr270-folge011", f"{_L1}/kjltvr111270r01", ("FOLGE011.LS",)),
    _ls("ls-ltvr270-up003", f"{_L1}/kjltvr111270r01", ("UP003.LS",)),
    _ls("ls-ltvr220-up003", f"{_L1}/kjltvr111220r01", ("UP003.LS",)),
    _ls("ls-ltvr220-folge125", f"{_L1}/kjltvr111220r01", ("FOLGE125.LS",)),
    _ls("ls-ltvr630-folge011", f"{_L1}/kjltvr411630r01", ("FOLGE011.LS",)),
    _ls("ls-ltvr630-folge125", f"{_L1}/kjltvr411630r01", ("FOLGE125.LS",)),
    _ls("ls-bvtu-german-folge011", f"{_BV}/GERMAN", ("FOLGE011.LS",)),
    _ls("ls-bvtu-english-folge125", f"{_BV}/ENGLISH", ("FOLGE125.LS",)),
    _weld("ls-weld-cub", "layers_splitter/data/cub.ls"),
    _weld("ls-weld-cub2", "layers_splitter/data/cub_2.ls"),
    _weld("ls-weld-layer1", "layers_splitter/data_result/layer_1.ls"),
    # URScript: PolyScope exports of a real UR10e, and UR's own example
    *(
        Program(
            f"ur-pharmbio-{n}",
            "urscript",
            _PH,
            "536ca11fd0c66c85ddf416c566e7151cf93df8f5",
            (f"programs/{n}.script",),
            "ur10e",
            "stated (repo notes.md)",
            "PolyScope export",
        )
        for n in (
            "dan_delid",
            "dan_disp_putget",
            "dan_incu_to_delid",
            "dan_lid_21_11",
            "dan_wash_putget",
        )
    ),
    Program(
        "ur-pharmbio-h21_r21",
        "urscript",
        _PH,
        "04e0e78050ec5379739c9905c30fe6f7472b3ad1",
        ("scripts/dan_h21_r21.script",),
        "ur10e",
        "stated (repo notes.md)",
        "PolyScope export",
    ),
    Program(
        "ur-pharmbio-wash_to_disp",
        "urscript",
        _PH,
        "5295958b1dd32096ca0c6980417010d8f41edea6",
        ("scripts/dan_wash_to_disp.script",),
        "ur10e",
        "stated (repo notes.md)",
        "PolyScope export",
    ),
    Program(
        "ur-examples-timing",
        "urscript",
        "UniversalRobots/URScript_Examples",
        "cb7e2bde5f0b01f7704f49e72d8c8d8ff2dd86aa",
        ("execution-time/timing_debug.script",),
        "ur5e",
        "best fit (bench/ur_factory.md)",
        "UR's example (PolyScope export)",
    ),
)

#: What-ifs (labelled "-no-eax"): the TACO modules write eax_a = 0 for an absent axis; run
#: again with a model file that says the controller drives no external axis.
WHAT_IFS: tuple[Program, ...] = tuple(
    replace(
        p,
        id=p.id + "-no-eax",
        no_external_axes=True,
        arm_source=p.arm_source + "; what-if",
        files_of=p.id,
    )
    for p in PROGRAMS
    if p.id.startswith("rapid-tp-")
)
