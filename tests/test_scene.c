// SPDX-License-Identifier: GPL-2.0-or-later
// Scene files: the bundled liver scene loads; defaults; every malformed input fails with a
// message naming the file, the line and the key; truncated files never crash.
#define _POSIX_C_SOURCE 200809L // mkdtemp, mkfifo
#include <stdlib.h>
#include <sys/stat.h>
#include <unistd.h>

#include "test_macros.h"

#include "mesh.h"
#include "scene.h"
#include "hapsim_channels.h"

#define LIVER HS_SOURCE_DIR "/scenes/liver/liver.json"

static int liver_scene_loads(void) {
    int64_t bytes0 = hs_byte_count();
    hs_scene s;
    hs_err err = {0};
    hs_status st = hs_scene_load(LIVER, &s, &err);
    if (st != HS_OK) printf("  %s\n", err.msg);
    ENSURE(st == HS_OK);
    ENSURE(strcmp(s.name, "liver") == 0);
    ENSURE(strcmp(s.mesh_path, HS_SOURCE_DIR "/scenes/liver/liver2.msh") == 0);
    ENSURE(s.model == HS_MODEL_COROTATED && s.rotation == HS_ROTATION_POLAR);
    ENSURE(s.material.youngs_pa == 5000.0 && s.material.poisson == 0.45);
    ENSURE(s.material.density_kg_m3 == 1060.0);
    ENSURE(s.n_fixed == 1 && s.fixed[0].kind == HS_FIXED_PLANE && s.fixed[0].normal[1] == 1.0);
    ENSURE(s.n_tools == 1 && s.tools[0].kind == HS_TOOL_PROBE && s.tools[0].radius == 0.005);
    ENSURE(s.gravity[2] == 0.0 && s.n_devices == 1 && s.has_workspace);
    ENSURE(s.feature_haptics && !s.feature_cutting && s.feature_visual && !s.cut_free_pieces_fall);
    ENSURE(s.haptic_hz == 1000.0 && s.sim_hz == 60.0 && s.watchdog_s == 0.1);
    ENSURE(strcmp(s.prefix, HAPSIM_DEFAULT_PREFIX) == 0);
    ENSURE(strcmp(s.haptic_url, HAPSIM_DEFAULT_HAPTIC_URL) == 0);
    ENSURE(strcmp(s.mesh_url, HAPSIM_DEFAULT_MESH_URL) == 0);
    ENSURE(hs_byte_count() == bytes0);
    return 0;
}

static int defaults_and_paths(void) {
    hs_scene s, d;
    hs_err err = {0};
    hs_scene_default(&d);
    // The defaults are the protocol's.
    ENSURE(strcmp(d.haptic_url, HAPSIM_DEFAULT_HAPTIC_URL) == 0);
    ENSURE(strcmp(d.mesh_url, HAPSIM_DEFAULT_MESH_URL) == 0);
    ENSURE(strcmp(d.prefix, HAPSIM_DEFAULT_PREFIX) == 0);
    const char* minimal = "{\"mesh\": \"m.msh\", \"fixed\": [{\"type\": \"box\", \"min\": [0,0,0],"
                          " \"max\": [1,1,1]}]}";
    ENSURE(hs_scene_parse(minimal, "/a/b/scene.json", 0, &s, &err) == HS_OK);
    ENSURE(strcmp(s.mesh_path, "/a/b/m.msh") == 0 && strcmp(s.name, "scene.json") == 0);
    ENSURE(s.material.youngs_pa == d.material.youngs_pa && s.model == d.model);
    ENSURE(s.solver == HS_SCENE_SOLVER_AUTO && d.solver == HS_SCENE_SOLVER_AUTO &&
           !s.exact_tangent);
    const char* warped = "{\"mesh\": \"m.msh\", \"model\": {\"solver\": \"warped\"}, \"fixed\": "
                         "[{\"type\": \"box\", \"min\": [0,0,0], \"max\": [1,1,1]}]}";
    ENSURE(hs_scene_parse(warped, "/a/b/scene.json", 0, &s, &err) == HS_OK &&
           s.solver == HS_SCENE_SOLVER_WARPED);
    ENSURE(s.n_tools == d.n_tools && s.haptic_hz == d.haptic_hz && !s.has_workspace);
    ENSURE(s.fixed[0].kind == HS_FIXED_BOX && s.fixed[0].max[2] == 1.0);
    const char* pcg =
        "{\"mesh\": \"m.msh\", \"model\": {\"solver\": \"pcg\", \"solver_accuracy\": "
        "\"tangent\"}, \"fixed\": [{\"type\": \"box\", \"min\": [0,0,0], \"max\": [1,1,1]}]}";
    ENSURE(hs_scene_parse(pcg, "/a/b/scene.json", 0, &s, &err) == HS_OK &&
           s.solver == HS_SCENE_SOLVER_PCG && s.exact_tangent);
    const char* bad = "{\"mesh\": \"m.msh\", \"model\": {\"solver\": \"cg\"}, \"fixed\": "
                      "[{\"type\": \"box\", \"min\": [0,0,0], \"max\": [1,1,1]}]}";
    ENSURE(hs_scene_parse(bad, "/a/b/scene.json", 0, &s, &err) != HS_OK &&
           strstr(err.msg, "model.solver") && strstr(err.msg, "auto | direct | warped | pcg"));
    ENSURE(hs_scene_parse(minimal, "scene.json", 0, &s, &err) == HS_OK);
    ENSURE(strcmp(s.mesh_path, "m.msh") == 0);
    const char* abs = "{\"mesh\": \"/x/m.msh\", \"fixed\": [{\"type\": \"bbox_side\", \"axis\": "
                      "\"z\", \"side\": \"min\", \"depth\": 0.01}], \"_note\": [1, 2]}";
    ENSURE(hs_scene_parse(abs, "/a/b/scene.json", 0, &s, &err) == HS_OK);
    ENSURE(strcmp(s.mesh_path, "/x/m.msh") == 0);
    ENSURE(s.fixed[0].kind == HS_FIXED_BBOX_SIDE && s.fixed[0].axis == 2 && s.fixed[0].side == -1 &&
           s.fixed[0].depth == 0.01);
    // A plane normal is normalised; a scalpel scene with cutting parses.
    const char* cut =
        "{\"mesh\": \"m.msh\", \"fixed\": [{\"type\": \"plane\", \"point\": [0,0,0],"
        " \"normal\": [0,0,2]}], \"tools\": [{\"kind\": \"probe\", \"radius\": 0.004},"
        " {\"kind\": \"scalpel\", \"blade_a\": [0,0,0], \"blade_b\": [0,0,0.02]}],"
        " \"features\": {\"cutting\": true}, \"cutting\": {\"free_pieces\": \"fall\"},"
        " \"lcm\": {\"prefix\": \"\"}}";
    ENSURE(hs_scene_parse(cut, "c.json", 0, &s, &err) == HS_OK);
    ENSURE(s.fixed[0].normal[2] == 1.0 && s.n_tools == 2 && s.tools[1].kind == HS_TOOL_SCALPEL);
    ENSURE(s.feature_cutting == 1 && s.cut_free_pieces_fall == 1 && s.prefix[0] == '\0');
    ENSURE(strcmp(hs_scene_model_name(HS_MODEL_STVK), "stvk") == 0);
    // model.locking_free: true is the model's default mode (SNS; ANP for StVK), or a name.
    const char* lf[][2] = {{"\"corotated\", \"locking_free\": true", "2"},
                           {"\"stvk\", \"locking_free\": true", "1"},
                           {"\"linear\", \"locking_free\": false", "0"},
                           {"\"corotated\", \"locking_free\": \"anp\"", "1"},
                           {"\"linear\", \"locking_free\": \"sns\"", "2"},
                           {"\"corotated\", \"locking_free\": \"none\"", "0"}};
    for (size_t k = 0; k < sizeof lf / sizeof lf[0]; ++k) {
        char text[512];
        snprintf(text, sizeof text,
                 "{\"mesh\": \"m.msh\", \"model\": {\"type\": %s}, \"fixed\": "
                 "[{\"type\": \"box\", \"min\": [0,0,0], \"max\": [1,1,1]}]}",
                 lf[k][0]);
        ENSURE(hs_scene_parse(text, "s.json", 0, &s, &err) == HS_OK);
        ENSURE(s.locking_free == atoi(lf[k][1]));
    }
    return 0;
}

// Parse text that must fail; the message must contain every needle.
static int expect_fail(const char* text, hs_status code, const char* n1, const char* n2) {
    hs_scene s;
    hs_err err = {0};
    hs_status st = hs_scene_parse(text, "t.json", 0, &s, &err);
    if (st != code || !strstr(err.msg, n1) || (n2 && !strstr(err.msg, n2))) {
        printf("  got %d '%s', wanted %d with '%s' '%s'\n", st, err.msg, code, n1, n2 ? n2 : "");
        return 1;
    }
    // On failure the struct holds defaults, not a half-filled scene.
    hs_scene d;
    hs_scene_default(&d);
    ENSURE(s.material.youngs_pa == d.material.youngs_pa && s.n_fixed == 0);
    return 0;
}

#define HEAD                                                                                       \
    "{\n\"mesh\": \"m.msh\",\n\"fixed\": [{\"type\": \"box\", \"min\": [0,0,0], \"max\": "         \
    "[1,1,1]}],\n"

static int malformed_names_file_line_key(void) {
    // Syntax errors: file, line and column.
    ENSURE(expect_fail("{\n  \"mesh\": \"m.msh\"\n  \"fixed\": []\n}", HS_ERR_PARSE,
                       "t.json:3:", "malformed JSON") == 0);
    ENSURE(expect_fail("", HS_ERR_PARSE, "t.json:1:", "malformed") == 0);
    ENSURE(expect_fail("{\"mesh\": \"m.msh\"} trailing", HS_ERR_PARSE, "t.json:1:", NULL) == 0);
    // Lines that end in \r\n or a lone \r (old Mac files) count as lines: the lone \r ones all
    // said line 1 before.
#define FIXED "\"fixed\": [{\"type\": \"box\", \"min\": [0,0,0], \"max\": [1,1,1]}],"
    ENSURE(expect_fail("{\r\"mesh\": \"m.msh\",\r" FIXED "\r\"devices\": 99}", HS_ERR_PARSE,
                       "t.json:4:", "'devices'") == 0);
    ENSURE(expect_fail("{\r\n\"mesh\": \"m.msh\",\r\n" FIXED "\r\n\"devices\": 99}", HS_ERR_PARSE,
                       "t.json:4:", "'devices'") == 0);
#undef FIXED
    ENSURE(expect_fail("{\r  \"mesh\": \"m.msh\"\r  \"fixed\": []\r}", HS_ERR_PARSE,
                       "t.json:3:3:", "malformed JSON") == 0);
    // Keys: each problem names the key path and the line it is on.
    ENSURE(expect_fail(HEAD "\"material\": {\"poisson\": \"a\"}}", HS_ERR_PARSE,
                       "t.json:4:", "'material.poisson': must be a number") == 0);
    ENSURE(expect_fail(HEAD "\"material\": {\n \"poisson\": 0.5}}", HS_ERR_PARSE,
                       "t.json:5:", "'material.poisson': must be in (-1, 0.4999]") == 0);
    // The same after a UTF-8 byte order mark (it was taken for the '{': line 3).
    ENSURE(expect_fail("\xEF\xBB\xBF" HEAD "\"material\": {\n \"poisson\": 0.5}}", HS_ERR_PARSE,
                       "t.json:5:", "'material.poisson': must be in (-1, 0.4999]") == 0);
    ENSURE(expect_fail(HEAD "\"material\": {\n\n \"young\": 5}}", HS_ERR_PARSE,
                       "t.json:6:", "'material.young': unknown key") == 0);
    ENSURE(expect_fail(HEAD "\"devices\": 1,\n\"devices\": 2}", HS_ERR_PARSE,
                       "t.json:5:", "'devices': appears twice") == 0);
    ENSURE(expect_fail(HEAD "\"devices\": 1.5}", HS_ERR_PARSE, "'devices': must be an integer",
                       NULL) == 0);
    ENSURE(expect_fail("{\"fixed\": []}", HS_ERR_PARSE, "'mesh': is required", NULL) == 0);
    ENSURE(expect_fail("{\"mesh\": \"m\"}", HS_ERR_PARSE, "'fixed': is required", NULL) == 0);
    ENSURE(expect_fail("{\"mesh\": \"m\", \"fixed\": []}", HS_ERR_PARSE, "'fixed': needs 1 to",
                       NULL) == 0);
    ENSURE(expect_fail("{\"mesh\": \"m\",\n\"fixed\": [{\"type\": \"box\", \"min\": [0,0,0], "
                       "\"max\": [1,1,1]},\n {\"type\": \"plane\", \"point\": [0,0,0],\n "
                       "\"normal\": [0,0,0]}]}",
                       HS_ERR_PARSE, "t.json:4:", "'fixed[1].normal': must not be zero") == 0);
    ENSURE(expect_fail("{\"mesh\": \"m\", \"fixed\": [{\"type\": \"box\", \"min\": [0,0,0], "
                       "\"max\": [1,-1,1]}]}",
                       HS_ERR_PARSE, "'fixed[0].max': is below min in component 1", NULL) == 0);
    ENSURE(expect_fail("{\"mesh\": \"m\", \"fixed\": [{\"type\": \"cone\"}]}", HS_ERR_PARSE,
                       "'fixed[0].type': must be one of: plane | box | bbox_side", NULL) == 0);
    ENSURE(expect_fail(HEAD "\"model\": {\"type\": \"neohookean\"}}", HS_ERR_PARSE,
                       "'model.type': must be one of: linear | corotated | stvk", NULL) == 0);
    ENSURE(expect_fail(HEAD "\"model\": {\"locking_free\": 1}}", HS_ERR_PARSE,
                       "'model.locking_free': must be true, false, none, anp or sns", NULL) == 0);
    ENSURE(expect_fail(HEAD "\"model\": {\"locking_free\": \"fbar\"}}", HS_ERR_PARSE,
                       "'model.locking_free': must be one of: none | anp | sns", NULL) == 0);
    ENSURE(expect_fail(HEAD "\"model\": {\"type\": \"stvk\", \"locking_free\": \"sns\"}}",
                       HS_ERR_PARSE, "'model.locking_free': sns is for linear and corotated",
                       NULL) == 0);
    ENSURE(expect_fail(HEAD "\"model\": {\"solver\": \"cg\"}}", HS_ERR_PARSE,
                       "'model.solver': must be one of: auto | direct | warped | pcg", NULL) == 0);
    ENSURE(expect_fail(HEAD "\"model\": {\"solver_accuracy\": \"exact\"}}", HS_ERR_PARSE,
                       "'model.solver_accuracy': must be one of: equilibrium | tangent",
                       NULL) == 0);
    ENSURE(expect_fail(HEAD "\"gravity\": [0, 0]}", HS_ERR_PARSE,
                       "'gravity': must be an array of 3", NULL) == 0);
    ENSURE(expect_fail(HEAD "\"tools\": [{\"kind\": \"probe\"}]}", HS_ERR_PARSE,
                       "'tools[0].radius': is required", NULL) == 0);
    ENSURE(expect_fail(HEAD "\"tools\": [{\"kind\": \"scalpel\", \"blade_a\": [0,0,0], "
                            "\"blade_b\": [0,0,0]}]}",
                       HS_ERR_PARSE, "'tools[0].blade_b': equals blade_a", NULL) == 0);
    ENSURE(expect_fail(HEAD "\"features\": {\"cutting\": true}}", HS_ERR_PARSE,
                       "'features.cutting': is on but no tool is a scalpel", NULL) == 0);
    ENSURE(expect_fail(HEAD "\"cutting\": {\"free_pieces\": \"fix\"}}", HS_ERR_PARSE,
                       "'cutting.free_pieces': must be one of: drop | fall", NULL) == 0);
    ENSURE(expect_fail(HEAD "\"cutting\": {\"orphans\": \"pin\"}}", HS_ERR_PARSE,
                       "'cutting.orphans'", NULL) == 0);
    ENSURE(expect_fail(HEAD "\"tools\": [], \"features\": {\"haptics\": true}}", HS_ERR_PARSE,
                       "'features.haptics'", NULL) == 0);
    // Each fixed region keeps its line, for the server's messages about what it selects.
    hs_scene sp;
    hs_err pe = {0};
    ENSURE(hs_scene_parse(HEAD "\"devices\": 1}", "t.json", 0, &sp, &pe) == HS_OK);
    ENSURE(sp.n_fixed == 1 && sp.fixed[0].line == 3);
    // Without a features object the message still has a line (the tools').
    ENSURE(expect_fail(HEAD "\"tools\": []}", HS_ERR_PARSE, "t.json:4: key 'features.haptics'",
                       NULL) == 0);
    // Cutting needs haptics (it loaded, said it cut, and never did).
    ENSURE(expect_fail(HEAD "\"tools\": [{\"kind\": \"scalpel\", \"blade_a\": [0,0,0], "
                            "\"blade_b\": [0,0,0.01]}],\n\"features\": {\"haptics\": false, "
                            "\"cutting\": true}}",
                       HS_ERR_PARSE, "t.json:5: key 'features.cutting': needs features.haptics",
                       NULL) == 0);
    // One probe and one scalpel: a second probe's tool_id was answered as the first probe.
    ENSURE(expect_fail(HEAD "\"tools\": [{\"kind\": \"probe\", \"radius\": 0.005},\n "
                            "{\"kind\": \"probe\", \"radius\": 0.02}]}",
                       HS_ERR_PARSE, "t.json:5: key 'tools[1]': a second probe", NULL) == 0);
    // A visual rate whose period overflows the server's clock (1e-12 Hz stalled its loop), a
    // Poisson ratio where the volumetric term swamps the rest, a modulus no probe can feel.
    ENSURE(expect_fail(HEAD "\"rates\": {\"visual_hz\": 1e-12}}", HS_ERR_PARSE,
                       "'rates.visual_hz': must be in [0.1, 240]", NULL) == 0);
    ENSURE(expect_fail(HEAD "\"material\": {\"poisson\": 0.4999999999}}", HS_ERR_PARSE,
                       "'material.poisson'", NULL) == 0);
    ENSURE(expect_fail(HEAD "\"material\": {\"youngs_pa\": 1e-300}}", HS_ERR_PARSE,
                       "'material.youngs_pa': must be in [1, 1e+12]", NULL) == 0);
    ENSURE(expect_fail(HEAD "\"lcm\": {\"mesh_url\": \"udpm://239.255.76.67:7667?ttl=0\"}}",
                       HS_ERR_PARSE, "'lcm.mesh_url': must differ", NULL) == 0);
    // Options after '?' (ttl, recv_buf_size) do not make a second bus: same group and port.
    ENSURE(expect_fail(HEAD "\"lcm\": {\"mesh_url\": \"udpm://239.255.76.67:7667?ttl=1\"}}",
                       HS_ERR_PARSE, "'lcm.mesh_url': must differ", NULL) == 0);
    ENSURE(expect_fail(HEAD "\"lcm\": {\"haptic_url\": \"udpm://239.255.76.67:7668\"}}",
                       HS_ERR_PARSE, "'lcm.mesh_url': must differ", NULL) == 0);
    ENSURE(expect_fail(HEAD "\"lcm\": {\"prefix\": \"hapsim.\"}}", HS_ERR_PARSE,
                       "'lcm.prefix': may contain only", NULL) == 0);
    ENSURE(expect_fail(HEAD "\"lcm\": {\"haptic_url\": \"localhost\"}}", HS_ERR_PARSE,
                       "'lcm.haptic_url': is not an LCM URL", NULL) == 0);
    // A group without a port is a random port to LCM 1.3.1 (a bus no one hears; accepted before).
    ENSURE(expect_fail(HEAD "\"lcm\": {\"haptic_url\": \"udpm://239.255.76.67?ttl=0\"}}",
                       HS_ERR_PARSE, "'lcm.haptic_url': names a group but no port", NULL) == 0);
    ENSURE(expect_fail(HEAD "\"lcm\": {\"mesh_url\": \"udpm://239.255.76.67:\"}}", HS_ERR_PARSE,
                       "'lcm.mesh_url': names a group but no port", NULL) == 0);
    ENSURE(expect_fail(HEAD "\"lcm\": {\"mesh_url\": \"udpm://239.255.76.67:0x0?ttl=0\"}}",
                       HS_ERR_PARSE, "'lcm.mesh_url': has port 0 or one outside", NULL) == 0);
    ENSURE(expect_fail(HEAD "\"lcm\": {\"mesh_url\": \"udpm://239.255.76.67:4294967296\"}}",
                       HS_ERR_PARSE, "outside 1..65535", NULL) == 0); // an int in LCM: 0
    // A \u0000 escape cut the mesh path short ("m.msh\u0000junk" loaded m.msh) and a raw
    // newline inside a string passed: JSON allows neither.
    ENSURE(expect_fail("{\"mesh\": \"m.msh\\u0000junk\", \"fixed\": []}", HS_ERR_PARSE,
                       "t.json:1:", "\\u0000 inside a string") == 0);
    ENSURE(expect_fail(HEAD "\"name\": \"a\nb\"}", HS_ERR_PARSE,
                       "t.json:4:", "a control byte inside a string") == 0);
    ENSURE(expect_fail(HEAD "\"name\": \"tab\there\"}", HS_ERR_PARSE,
                       "t.json:4:", "control byte") == 0);
    // Escaped control characters decode to control bytes: refused in the values read.
    ENSURE(expect_fail(HEAD "\"name\": \"a\\u001bb\"}", HS_ERR_PARSE, "'name'",
                       "escaped control character (byte 0x1b)") == 0);
    ENSURE(expect_fail(HEAD "\"name\": \"a\\u0001\"}", HS_ERR_PARSE, "'name'",
                       "escaped control character (byte 0x01)") == 0);
    ENSURE(expect_fail(HEAD "\"name\": \"a\\nb\"}", HS_ERR_PARSE, "'name'",
                       "escaped control character") == 0);
    // LCM reads "7667x" as port 7667: the haptic bus's, which the text comparison missed.
    ENSURE(expect_fail(HEAD "\"lcm\": {\"mesh_url\": \"udpm://239.255.76.67:7667x?ttl=0\"}}",
                       HS_ERR_PARSE, "'lcm.mesh_url': has a port that is not a number alone",
                       NULL) == 0);
    ENSURE(expect_fail(HEAD "\"lcm\": {\"haptic_url\": \"udpm://239.255.76.67:abc\"}}",
                       HS_ERR_PARSE, "not a number alone", NULL) == 0);
    ENSURE(expect_fail(HEAD "\"lcm\": {\"mesh_url\": \"udpm://239.255.76.67:7668 \"}}",
                       HS_ERR_PARSE, "not a number alone", NULL) == 0);
    ENSURE(expect_fail(HEAD "\"rates\": {\"haptic_hz\": 100, \"sim_hz\": 200}}", HS_ERR_PARSE,
                       "'rates.sim_hz'", NULL) == 0);
    ENSURE(expect_fail(HEAD "\"rates\": {\"haptic_hz\": 1e400}}", HS_ERR_PARSE, "'rates.haptic_hz'",
                       NULL) == 0);
    ENSURE(expect_fail("[1, 2]", HS_ERR_PARSE, "(top level)", NULL) == 0);
    // Many keys in one object: refused at once rather than checked pairwise for repeats (a
    // 979 kB file of 90 000 comment keys took 24 s before).
    char* big = malloc(40000);
    ENSURE(big != NULL);
    size_t len = (size_t)snprintf(big, 40000, "%s", HEAD);
    for (int k = 0; k < 1000; k++)
        len += (size_t)snprintf(big + len, 40000 - len, "\"_%d\": 0, ", k);
    snprintf(big + len, 40000 - len, "\"devices\": 1}");
    ENSURE(expect_fail(big, HS_ERR_PARSE, "more than 256 keys in one object", NULL) == 0);
    free(big);
    return 0;
}

// Two URLs are one bus when LCM would open the same provider, group and port.
static int same_bus(void) {
    ENSURE(hs_scene_same_bus("udpm://239.255.76.67:7667", "udpm://239.255.76.67:7667?ttl=0"));
    ENSURE(hs_scene_same_bus("udpm://239.255.76.67:7667?ttl=0", "udpm://?recv_buf_size=9"));
    ENSURE(hs_scene_same_bus("udpm://239.255.76.67:0x1DF3", "udpm://239.255.76.67:7667"));
    ENSURE(!hs_scene_same_bus("udpm://239.255.76.67:7667?ttl=0", "udpm://239.255.76.67:7668"));
    ENSURE(!hs_scene_same_bus("udpm://239.255.76.67:7667", "udpm://239.255.76.68:7667"));
    ENSURE(!hs_scene_same_bus("udpm://239.255.76.67:7667", "tcpq://239.255.76.67:7667"));
    ENSURE(hs_scene_same_bus("file:///tmp/a.log?mode=w", "file:///tmp/a.log"));
    ENSURE(!hs_scene_same_bus("file:///tmp/a.log", "file:///tmp/b.log"));
    return 0;
}

static int files_and_truncation(void) {
    int64_t bytes0 = hs_byte_count();
    hs_scene s;
    hs_err err = {0};
    ENSURE(hs_scene_load("/nonexistent/x.json", &s, &err) == HS_ERR_IO);
    ENSURE(strstr(err.msg, "/nonexistent/x.json") != NULL);
    ENSURE(hs_scene_load("/tmp", &s, &err) == HS_ERR_IO); // a directory
    ENSURE(strstr(err.msg, "not a regular file (a folder)") != NULL);
    // A FIFO with no writer is refused at once (open() would wait for a writer).
    char fifo[] = "/tmp/hs_test_scene_XXXXXX";
    ENSURE(mkdtemp(fifo) != NULL);
    char fpath[64];
    snprintf(fpath, sizeof fpath, "%s/scene.json", fifo);
    ENSURE(mkfifo(fpath, 0600) == 0);
    int64_t t0 = hs_now_ns();
    ENSURE(hs_scene_load(fpath, &s, &err) == HS_ERR_IO);
    ENSURE(strstr(err.msg, "not a regular file (a FIFO)") && strstr(err.msg, fpath));
    ENSURE(hs_now_ns() - t0 < 2000000000LL);
    unlink(fpath);
    // The same for a mesh (the readers' one whole-file reader).
    snprintf(fpath, sizeof fpath, "%s/organ.msh", fifo);
    ENSURE(mkfifo(fpath, 0600) == 0);
    hs_mesh* m = NULL;
    t0 = hs_now_ns();
    ENSURE(hs_mesh_load(fpath, &m, &err) == HS_ERR_IO && m == NULL);
    ENSURE(strstr(err.msg, "not a regular file (a FIFO)") && strstr(err.msg, fpath));
    ENSURE(hs_now_ns() - t0 < 2000000000LL);
    unlink(fpath);
    rmdir(fifo);
    // A mesh that does not exist is named with its resolved path.
    const char* text = "{\"mesh\": \"nope.msh\", \"fixed\": [{\"type\": \"box\", \"min\": [0,0,0],"
                       " \"max\": [1,1,1]}]}";
    ENSURE(hs_scene_parse(text, "/nonexistent/dir/s.json", 1, &s, &err) == HS_ERR_PARSE);
    ENSURE(strstr(err.msg, "/nonexistent/dir/nope.msh") && strstr(err.msg, "'mesh'"));

    // Every truncation of the liver scene fails cleanly; the whole file parses.
    FILE* f = fopen(LIVER, "rb");
    ENSURE(f != NULL);
    static char buf[1 << 16];
    size_t n = fread(buf, 1, sizeof buf - 1, f);
    fclose(f);
    ENSURE(n > 100 && n < sizeof buf - 1);
    char* scratch = malloc(n + 1);
    ENSURE(scratch != NULL);
    int ok = 0;
    for (size_t len = 0; len <= n; ++len) {
        memcpy(scratch, buf, len);
        scratch[len] = '\0';
        hs_status st = hs_scene_parse(scratch, LIVER, 0, &s, &err);
        if (st == HS_OK)
            ok++;
        else
            ENSURE(st == HS_ERR_PARSE && strstr(err.msg, "liver.json:") != NULL);
    }
    // Only the complete file, and the file missing just its final newline, are valid.
    ENSURE(ok >= 1 && ok <= 2);
    // Flip each byte to a quote: never crashes, errors always name the file.
    for (size_t i = 0; i < n; ++i) {
        memcpy(scratch, buf, n);
        scratch[n] = '\0';
        scratch[i] = scratch[i] == '"' ? '{' : '"';
        hs_status st = hs_scene_parse(scratch, LIVER, 0, &s, &err);
        if (st != HS_OK) ENSURE(strstr(err.msg, "liver.json") != NULL);
    }
    free(scratch);
    ENSURE(hs_byte_count() == bytes0);
    return 0;
}

HS_TEST_MAIN(HS_CASE(liver_scene_loads), HS_CASE(defaults_and_paths),
             HS_CASE(malformed_names_file_line_key), HS_CASE(files_and_truncation),
             HS_CASE(same_bus))
