use super::*;

fn invalid(text: &str) -> (usize, usize, String, String) {
    match Config::from_str(text, Some(Path::new("studio.toml"))).unwrap_err() {
        ConfigError::Invalid {
            path,
            line,
            column,
            key,
            message,
        } => {
            assert_eq!(path, Path::new("studio.toml"));
            (line, column, key, message)
        }
        ConfigError::Looks {
            path,
            line,
            column,
            key,
            source,
        } => {
            assert_eq!(path, Path::new("studio.toml"));
            (line, column, key, source.to_string())
        }
        other => panic!("{other}"),
    }
}

#[test]
fn embedded_defaults_set_every_key() {
    let c = Config::defaults();
    assert_eq!(c.folders.ingest, Path::new("ingest"));
    assert_eq!(c.folders.out, Path::new("out"));
    assert_eq!(c.folders.state, Path::new(".filmback"));
    assert_eq!(c.folders.archive, None);
    assert_eq!(c.watch.mode, WatchMode::Notify);
    assert_eq!(c.watch.settle, Duration::from_millis(1000));
    assert_eq!(c.watch.rescan, Some(Duration::from_secs(60)));
    assert_eq!(c.bracket.size, 3);
    assert_eq!(c.bracket.singles, Singles::Render);
    assert_eq!(c.daemon.jobs, 2);
    assert_eq!(c.render.films, vec!["velvia50".to_string()]);
    assert_eq!(c.render.tonemaps, vec!["linear".to_string()]);
    assert_eq!(c.render.recalibrate, Recalibrate::Auto);
    assert_eq!(c.render.luminance_calibration, 1.0);
    assert_eq!(c.render.primaries, crate::hdr_output::Primaries::Rec709);
    assert!(c.cameras.is_empty());
    // An empty file is the defaults.
    let empty = Config::from_str("", Some(Path::new("e.toml"))).unwrap();
    assert_eq!(empty.render, c.render);
    assert_eq!(empty.watch, c.watch);
}

#[test]
fn user_values_override_and_presets_match_model_then_serial() {
    let text = r#"
[folders]
ingest = "/srv/in"
[watch]
mode = "poll"
rescan_s = 0
[render]
films = ["provia400"]
t = 0.5
[camera."Canon EOS R5"]
films = ["velvia50", "ektachrome100"]
recalibrate = "never"
[camera.studio-b]
model = "Canon EOS R5"
serial = "042"
t = -1
"#;
    let c = Config::from_str(text, Some(Path::new("s.toml"))).unwrap();
    assert_eq!(c.folders.ingest, Path::new("/srv/in"));
    assert_eq!(c.folders.out, Path::new("out"));
    assert_eq!(c.watch.mode, WatchMode::Poll);
    assert_eq!(c.watch.rescan, None);
    let p = c.preset_for(Some("Canon EOS R5"), Some("001"));
    assert_eq!(p.name.as_deref(), Some("Canon EOS R5"));
    assert_eq!(p.films, vec!["velvia50", "ektachrome100"]);
    assert_eq!(p.t, 0.5, "inherits [render]");
    assert_eq!(p.recalibrate, Recalibrate::Never);
    let b = c.preset_for(Some("Canon EOS R5"), Some("042"));
    assert_eq!(b.name.as_deref(), Some("studio-b"));
    assert_eq!(b.t, -1.0);
    assert_eq!(b.films, vec!["provia400"]);
    let other = c.preset_for(Some("NIKON Z 8"), None);
    assert_eq!(other.name, None);
    assert_eq!(other.films, vec!["provia400"]);
    assert_eq!(c.preset_for(None, None).name, None);
}

#[test]
fn unknown_key_names_file_line_and_key() {
    let (line, _, key, message) = invalid("[watch]\nsettle_ms = 10\nsetle = 5\n");
    assert_eq!(line, 3);
    assert_eq!(key, "setle");
    assert!(message.contains("unknown field"), "{message}");
    let (line, _, key, _) = invalid("\n[camera.x]\nfilms = []\ncolour = 1\n");
    assert_eq!((line, key.as_str()), (4, "colour"));
    let (line, _, key, _) = invalid("[wach]\n");
    assert_eq!((line, key.as_str()), (1, "[wach]"));
}

#[test]
fn bad_values_name_line_key_and_range() {
    let (line, column, key, message) = invalid("[daemon]\njobs = 0\n");
    assert_eq!((line, column, key.as_str()), (2, 8, "jobs"));
    assert!(message.contains("outside 1..=64"), "{message}");
    let (_, _, key, message) = invalid("[bracket]\nsize = 2.5\n");
    assert_eq!(key, "size");
    assert!(message.contains("whole number"), "{message}");
    let (_, _, key, message) = invalid("[watch]\nmode = \"inotify\"\n");
    assert_eq!(key, "mode");
    assert!(message.contains("notify"), "{message}");
    let (_, _, key, message) = invalid("[render]\nfilms = [\"Velvia 50\"]\n");
    assert_eq!(key, "films");
    assert!(message.contains("not a valid name"), "{message}");
    let (_, _, key, _) = invalid("[render]\nmin_confidence = \"high\"\n");
    assert_eq!(key, "min_confidence");
    let (line, _, _, _) = invalid("[render\n");
    assert_eq!(line, 1);
    let msg = Config::from_str("[daemon]\njobs = -3\n", Some(Path::new("/etc/f.toml")))
        .unwrap_err()
        .to_string();
    assert!(msg.starts_with("/etc/f.toml:2:8: jobs: "), "{msg}");
}

#[test]
fn outputs_inside_the_ingest_folder_are_refused() {
    let err = Config::from_str("[folders]\nout = \"ingest\"\n", Some(Path::new("s.toml")))
        .unwrap_err()
        .to_string();
    assert!(err.starts_with("s.toml: [folders]: out = "), "{err}");
    let text = "[folders]\nout = \"ingest/out\"\n[watch]\nrecursive = true\n";
    assert!(Config::from_str(text, Some(Path::new("s.toml"))).is_err());
    let text = "[folders]\nout = \"ingest/out\"\n";
    assert!(Config::from_str(text, Some(Path::new("s.toml"))).is_ok());
}

#[test]
fn missing_file_is_a_read_error_naming_it() {
    let err = Config::load(Path::new("/nonexistent/filmback.toml")).unwrap_err();
    assert!(
        err.to_string().contains("/nonexistent/filmback.toml"),
        "{err}"
    );
}

#[test]
fn temporary_names_are_ignored() {
    let w = Config::defaults().watch;
    for name in [
        "IMG_1.JPG",
        "a.jpeg",
        "scan.tif",
        "x.png",
        "IMG_0001.CR3.jpg",
    ] {
        assert!(w.takes(name), "{name}");
    }
    for name in [
        ".IMG_1.jpg",
        "IMG_1.jpg.tmp",
        "IMG_1.jpg.part",
        "IMG_1.jpg~",
        "IMG_1.jpg.crdownload",
        ".~lock.jpg",
        "notes.txt",
        "IMG_1",
        ".a.jpg.filmback-tmp-12",
    ] {
        assert!(!w.takes(name), "{name}");
    }
}

#[test]
fn tethering_tools_litter_is_never_a_frame_even_with_an_empty_ignore_list() {
    let mut w = Config::defaults().watch;
    w.ignore.clear();
    w.recursive = true;
    for name in [
        "tmpfileAb3xQz",
        "IMG_1.xmp",
        "IMG_1.CR2.xmp",
        "IMG_1.cos",
        "IMG_1.cop",
        "IMG_1.cot",
        "IMG_1.comask",
        ".DS_Store",
        "._IMG_1.jpg",
        "Thumbs.db",
        "IMG_1.jpg.part",
        "IMG_1.jpg.crdownload",
        "IMG_1.jpg.tmp",
        ".IMG_1.CR2.filmback-tmp-7",
    ] {
        assert!(!w.takes(name), "{name}");
    }
    let root = Path::new("/in");
    assert!(w.takes_path(root, Path::new("/in/RAW/IMG_1.CR2")));
    assert!(w.takes_path(root, Path::new("/in/IMG_1.JPG")));
    for path in [
        "/in/CaptureOne/Cache/Proxies/IMG_1.jpg",
        "/in/Session/captureone/IMG_1.jpg",
        "/in/.thumbs/IMG_1.jpg",
        "/in/RAW/._IMG_1.CR2",
    ] {
        assert!(!w.takes_path(root, Path::new(path)), "{path}");
    }
    w.recursive = false;
    assert!(!w.takes_path(root, Path::new("/in/RAW/IMG_1.CR2")));
    assert!(w.takes_path(root, Path::new("/in/IMG_1.CR2")));
}

#[test]
fn glob() {
    assert!(glob_match("*.tmp", "a.tmp"));
    assert!(glob_match("*.tmp", ".tmp"));
    assert!(!glob_match("*.tmp", "a.tmpx"));
    assert!(glob_match("a*b*c", "aXXbYbc"));
    assert!(!glob_match("a*b*c", "aXXbY"));
    assert!(glob_match("*", ""));
}

// ---- films, tone maps and the stocks folder ----

fn load(text: &str) -> Result<Config, ConfigError> {
    Config::from_str(text, Some(Path::new("studio.toml")))
}

/// A copy of the built-in Velvia 50 file under another id, in `dir/<file>`.
fn user_stock(dir: &Path, file: &str, id: &str) {
    let velvia = include_str!("../../../curves/velvia50.toml");
    assert!(velvia.contains("id = \"velvia50\"\n"));
    let text = velvia
        .replace("id = \"velvia50\"\n", &format!("id = \"{id}\"\n"))
        .replace("name = \"Fujifilm", "name = \"Studio copy of Fujifilm");
    std::fs::write(dir.join(file), text).unwrap();
}

fn toml_string(path: &Path) -> String {
    format!("{:?}", path.to_str().unwrap())
}

#[test]
fn known_films_with_exposures_load() {
    let text = "[render]\nfilms = [\"velvia50\", \"provia400@1/2\", \"p1600@-1ev\"]\n\
                tonemaps = [\"linear\", \"histogram\", \"histogram-naive\"]\n\
                [camera.\"X\"]\nfilms = [\"ektachrome100@2\"]\ntonemaps = []\n";
    let c = load(text).unwrap();
    assert_eq!(c.render.films, ["velvia50", "provia400@1/2", "p1600@-1ev"]);
    assert_eq!(
        c.render.tonemaps,
        ["linear", "histogram", "histogram-naive"]
    );
    let x = c.preset_for(Some("X"), None);
    assert_eq!(x.films, ["ektachrome100@2"]);
    assert!(x.tonemaps.is_empty());
}

#[test]
fn unknown_stock_names_its_line_and_key() {
    // `velvia5` is a prefix of a good name that comes first, and appears unquoted in a
    // comment: the line reported is the one holding the bad name.
    let text = "# velvia5 was a typo\n[render]\nfilms = [\"velvia50\"]\n\
                [camera.\"X\"]\nt = 1\nfilms = [\"velvia50\",\n  \"velvia5\"]\n";
    let (line, _, key, message) = invalid(text);
    assert_eq!((line, key.as_str()), (7, "camera.\"X\".films"));
    assert!(
        message.contains("unknown film stock \"velvia5\""),
        "{message}"
    );
    assert!(
        message.contains("velvia50"),
        "lists the known stocks: {message}"
    );

    let (line, _, key, message) = invalid("\n\n[render]\nt = 0\nfilms = [\"velvia5\"]\n");
    assert_eq!((line, key.as_str()), (5, "render.films"));
    assert!(message.contains("\"velvia5\""), "{message}");
    let err = load("[render]\nfilms = [\"velvia5@1/2\"]\n")
        .unwrap_err()
        .to_string();
    assert!(
        err.starts_with("studio.toml:2:1: render.films: ") && err.contains("\"velvia5\""),
        "{err}"
    );
}

#[test]
fn negatives_render_and_an_option_without_sheet_data_is_refused() {
    let text = "[render]\nfilms = [\"velvia50\"]\n\n[camera.\"Canon EOS R5\"]\nt = 0.5\n\
                films = [\"velvia50\", \"portra400\", \"ektar100@1/2+print=-1/3\"]\n";
    if let Err(e) = load(text) {
        panic!("{e}");
    }
    // Kodak gives no RMS granularity for its negatives: +grain is refused, by line.
    let text = "[render]\nfilms = [\"velvia50\"]\n\n[camera.\"Canon EOS R5\"]\nt = 0.5\n\
                films = [\"velvia50\", \"portra400+grain\"]\n";
    let (line, _, key, message) = invalid(text);
    assert_eq!(line, 6);
    assert_eq!(key, "camera.\"Canon EOS R5\".films");
    assert!(message.contains("RMS granularity"), "{message}");
}

#[test]
fn unknown_tonemap_is_refused() {
    let (line, _, key, message) = invalid("[render]\nfilms = []\ntonemaps = [\"sepia\"]\n");
    assert_eq!((line, key.as_str()), (3, "render.tonemaps"));
    assert!(
        message.contains("\"sepia\"") && message.contains("unknown tone map"),
        "{message}"
    );
    let (line, _, key, _) = invalid("[camera.x]\ntonemaps = [\"linear\", \"velvia50\"]\n");
    assert_eq!((line, key.as_str()), (2, "camera.\"x\".tonemaps"));
}

#[test]
fn bad_film_exposure_fails_while_parsing() {
    let (line, column, key, message) = invalid("[render]\nt = 1\nfilms = [\"velvia50@abc\"]\n");
    assert_eq!((line, key.as_str()), (3, "films"));
    assert!(column > 1, "points into the value: column {column}");
    assert!(message.contains("velvia50@abc"), "{message}");
    assert!(message.contains("abc"), "{message}");
    for bad in ["velvia50@0", "velvia50@-1", "@1/2", "velvia50@1/0"] {
        let (_, _, key, message) = invalid(&format!("[render]\nfilms = [\"{bad}\"]\n"));
        assert_eq!(key, "films", "{bad}");
        assert!(message.contains(bad), "{bad}: {message}");
    }
}

#[test]
fn stocks_folder_adds_user_stocks() {
    let stocks = tempfile::tempdir().unwrap();
    user_stock(stocks.path(), "studio.toml", "studio-slide");
    let text = format!(
        "[folders]\nstocks = {}\n[render]\nfilms = [\"studio-slide\", \"studio-slide@1/2\", \"velvia50\"]\n",
        toml_string(stocks.path())
    );
    let c = load(&text).unwrap();
    assert_eq!(c.folders.stocks.as_deref(), Some(stocks.path()));
    assert_eq!(
        c.render.films,
        ["studio-slide", "studio-slide@1/2", "velvia50"]
    );
    // Without the folder the same name is unknown.
    let (line, _, key, message) = invalid("[render]\nfilms = [\"studio-slide\", \"velvia50\"]\n");
    assert_eq!((line, key.as_str()), (2, "render.films"));
    assert!(message.contains("studio-slide"), "{message}");
    // Another folder's stocks do not count.
    let empty = tempfile::tempdir().unwrap();
    let text = format!(
        "[folders]\nstocks = {}\n[camera.x]\nfilms = [\"studio-slide\"]\n",
        toml_string(empty.path())
    );
    let (line, _, key, _) = invalid(&text);
    assert_eq!((line, key.as_str()), (4, "camera.\"x\".films"));
}

#[test]
fn bad_stocks_folder_is_refused_at_its_key() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("missing");
    let text = format!(
        "[render]\nfilms = [\"velvia50\"]\n[folders]\nstocks = {}\n",
        toml_string(&missing)
    );
    let (line, _, key, message) = invalid(&text);
    assert_eq!((line, key.as_str()), (4, "folders.stocks"));
    assert!(message.contains("missing"), "{message}");
    // The line of the key, not of an earlier mention of the word.
    let text = format!(
        "# stocks: see below\n[folders]\nout = \"/srv/stocks-out\"\nstocks = {}\n",
        toml_string(&missing)
    );
    let (line, _, key, _) = invalid(&text);
    assert_eq!((line, key.as_str()), (4, "folders.stocks"));

    // A user stock reusing a built-in id.
    user_stock(dir.path(), "dup.toml", "velvia50");
    let text = format!("[folders]\nstocks = {}\n", toml_string(dir.path()));
    let (line, _, key, message) = invalid(&text);
    assert_eq!((line, key.as_str()), (2, "folders.stocks"));
    assert!(message.contains("already defined"), "{message}");
}

#[test]
fn errors_in_the_example_file_point_at_the_edited_line() {
    // The shipped example, copied and edited: the stocks folder enabled (it does not
    // exist) and a film replaced. Its comments mention both.
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("no-such-stocks");
    let line_holding =
        |text: &str, needle: &str| text.lines().position(|l| l.starts_with(needle)).unwrap() + 1;
    let text = DEFAULT_TOML.replace(
        "# stocks = \"stocks\"",
        &format!("stocks = {}", toml_string(&missing)),
    );
    let (line, _, key, _) = invalid(&text);
    assert_eq!(key, "folders.stocks");
    assert_eq!(line, line_holding(&text, "stocks = "));

    let text = DEFAULT_TOML.replace("films = [\"velvia50\"]", "films = [\"provia100\"]");
    let (line, _, key, message) = invalid(&text);
    assert_eq!(key, "render.films");
    assert_eq!(line, line_holding(&text, "films = [\"provia100\"]"));
    assert!(message.contains("provia100"), "{message}");
}

/// `luminance_calibration` and `primaries`: per camera over `[render]`, checked where
/// they are written.
#[test]
fn luminance_calibration_and_primaries_are_checked() {
    let text =
        "[render]\nprimaries = \"ap1\"\n[camera.\"Canon EOS R5\"]\nluminance_calibration = 1.25\n";
    let c = Config::from_str(text, Some(Path::new("s.toml"))).unwrap();
    assert_eq!(c.render.primaries, crate::hdr_output::Primaries::Ap1);
    assert_eq!(c.render.luminance_calibration, 1.0);
    let r5 = c.preset_for(Some("Canon EOS R5"), None);
    assert_eq!(r5.luminance_calibration, 1.25);
    assert_eq!(r5.primaries, crate::hdr_output::Primaries::Ap1);
    let (line, _, key, message) = invalid("[render]\nluminance_calibration = 0\n");
    assert_eq!((line, key.as_str()), (2, "luminance_calibration"));
    assert!(message.contains("outside"), "{message}");
    let (_, _, key, message) = invalid("[render]\nprimaries = \"aces\"\n");
    assert_eq!(key, "primaries");
    assert!(message.contains("ap0"), "{message}");
}

/// `hdr_still`: off by default, per camera over `[render]`, and the lab's renderings then
/// are gain-map JPEGs under the same names.
#[test]
fn hdr_still_is_per_camera() {
    let c = Config::from_str("", Some(Path::new("s.toml"))).unwrap();
    assert!(!c.render.hdr_still);
    let text = "[render]\nhdr_still = true\n[camera.\"Canon EOS R5\"]\nhdr_still = false\n";
    let c = Config::from_str(text, Some(Path::new("s.toml"))).unwrap();
    assert!(c.render.hdr_still);
    assert!(!c.preset_for(Some("Canon EOS R5"), None).hdr_still);
    let (line, _, key, _) = invalid("[render]\nhdr_still = \"gainmap\"\n");
    assert_eq!((line, key.as_str()), (2, "hdr_still"));
}

/// `ghost_map`: off by default, per camera over `[render]`.
#[test]
fn ghost_map_is_per_camera() {
    let c = Config::from_str("", Some(Path::new("s.toml"))).unwrap();
    assert!(!c.render.ghost_map);
    let text = "[render]\nghost_map = true\n[camera.\"Canon EOS R5\"]\nghost_map = false\n";
    let c = Config::from_str(text, Some(Path::new("s.toml"))).unwrap();
    assert!(c.render.ghost_map);
    assert!(!c.preset_for(Some("Canon EOS R5"), None).ghost_map);
    let (line, _, key, _) = invalid("[render]\nghost_map = \"yes\"\n");
    assert_eq!((line, key.as_str()), (2, "ghost_map"));
}

/// `colour_space`: sRGB by default, per camera over `[render]`, a bad name refused with
/// the names it takes.
#[test]
fn colour_space_is_per_camera_and_checked() {
    use crate::display::ColourSpace;
    let c = Config::from_str("", Some(Path::new("s.toml"))).unwrap();
    assert_eq!(c.render.colour_space, ColourSpace::Srgb);
    let text =
        "[render]\ncolour_space = \"p3\"\n[camera.\"Canon EOS R5\"]\ncolour_space = \"rec2020\"\n";
    let c = Config::from_str(text, Some(Path::new("s.toml"))).unwrap();
    assert_eq!(c.render.colour_space, ColourSpace::DisplayP3);
    let r5 = c.preset_for(Some("Canon EOS R5"), None);
    assert_eq!(r5.colour_space, ColourSpace::Rec2020);
    let (line, _, key, message) = invalid("[render]\ncolour_space = \"adobe\"\n");
    assert_eq!((line, key.as_str()), (2, "colour_space"));
    assert!(message.contains("rec2020"), "{message}");
}
