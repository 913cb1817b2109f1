use gtsr_eval::{FINAL_LABEL, Timeline, TimelinePoint, plot_png};
use gtsr_eval::{ReportRow, format_duration, markdown_table, seed_summary_table, write_markdown};

fn timeline(label: &str, scale: f64, with_chamfer: bool) -> Timeline {
    timeline_with(label, scale, with_chamfer, false)
}

fn timeline_with(label: &str, scale: f64, with_chamfer: bool, with_depth: bool) -> Timeline {
    let mut t = Timeline::new();
    for k in 0..8u64 {
        t.push(TimelinePoint {
            iteration: k * 1000,
            train_seconds: k as f64 * 12.5 * scale,
            psnr: 20.0 + 2.0 * (k as f64).sqrt() * scale,
            ssim: 0.8 + 0.01 * k as f64,
            chamfer: (with_chamfer && k % 2 == 0).then(|| 0.05 / (1.0 + k as f64)),
            // Inside the chamfer's own range, so that the extra curves leave the axis as it is.
            depth_only_chamfer: (with_chamfer && with_depth && k % 2 == 0)
                .then(|| 0.04 / (1.0 + 0.5 * k as f64)),
            masks_alone_chamfer: (with_chamfer && with_depth).then_some(0.03),
            depth_error: (with_depth && k > 0).then(|| 0.02 / (k as f64).sqrt()),
            blind_completeness: None,
            rest_completeness: None,
            masks_alone_blind_completeness: None,
            masks_alone_rest_completeness: None,
            mesh_change: None,
            gaussians: 10_000 + 5_000 * k,
            label: label.to_string(),
        });
    }
    t
}

/// `series` plotted to `path` ([`plot_png`]) and read back.
fn plotted(path: &std::path::Path, series: &[(&str, &Timeline)]) -> image::RgbImage {
    plot_png(path, series).unwrap();
    image::open(path).unwrap().to_rgb8()
}

/// How many pixels of columns `x0..x1` differ between two images of one size.
fn differing_pixels(a: &image::RgbImage, b: &image::RgbImage, x0: u32, x1: u32) -> usize {
    (a.enumerate_pixels().zip(b.pixels()))
        .filter(|((x, _, p), q)| *x >= x0 && *x < x1 && p != q)
        .count()
}

#[test]
fn csv_round_trips_exactly() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("timeline.csv");
    let mut t = timeline_with("gtsr, \"full\"", 1.0, true, true);
    t.points[3].psnr = 1.0 / 3.0;
    t.write_csv(&path).unwrap();
    let back = Timeline::read_csv(&path).unwrap();
    assert_eq!(back, t);
    assert!(back.points.iter().any(|p| p.depth_only_chamfer.is_some()));
    assert!(
        back.points
            .iter()
            .all(|p| p.masks_alone_chamfer == Some(0.03))
    );
    // Logs written before the depth-only and masks-alone columns still read, without them.
    std::fs::write(
        &path,
        "iteration,train_seconds,psnr,ssim,chamfer,depth_error,gaussians,label
1,2,3,0.5,0.01,0.02,5,a
",
    )
    .unwrap();
    let v2 = Timeline::read_csv(&path).unwrap();
    assert_eq!(
        (
            v2.points[0].chamfer,
            v2.points[0].depth_only_chamfer,
            v2.points[0].masks_alone_chamfer,
            v2.points[0].depth_error
        ),
        (Some(0.01), None, None, Some(0.02))
    );
    assert_eq!(
        (v2.points[0].gaussians, v2.points[0].label.as_str()),
        (5, "a")
    );
    // A column out of place is refused.
    std::fs::write(
        &path,
        "iteration,train_seconds,psnr,ssim,depth_error,chamfer,gaussians,label
1,2,3,0.5,0.01,0.02,5,a
",
    )
    .unwrap();
    let e = Timeline::read_csv(&path).unwrap_err().to_string();
    assert!(e.contains("line 1") && e.contains("expected header"), "{e}");
    // Logs written before the depth error column still read, without it.
    std::fs::write(
        &path,
        "iteration,train_seconds,psnr,ssim,chamfer,gaussians,label\n1,2,3,0.5,0.01,5,a\n",
    )
    .unwrap();
    let old = Timeline::read_csv(&path).unwrap();
    assert_eq!(old.points[0].chamfer, Some(0.01));
    assert_eq!(old.points[0].depth_error, None);
    assert_eq!(
        (old.points[0].gaussians, old.points[0].label.as_str()),
        (5, "a")
    );
    std::fs::write(
        &path,
        "iteration,train_seconds,psnr,ssim,chamfer,depth_only_chamfer,masks_alone_chamfer,depth_error,gaussians,label\n1,2,3,0.5,,,,0.02,5\n",
    )
    .unwrap();
    let e = Timeline::read_csv(&path).unwrap_err().to_string();
    assert!(e.contains("expected 10 fields"), "{e}");
    // No temporary file left behind.
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    std::fs::write(
        &path,
        "iteration,train_seconds,psnr,ssim,chamfer,gaussians,label\n1,2,x,4,,5,a\n",
    )
    .unwrap();
    let e = Timeline::read_csv(&path).unwrap_err().to_string();
    assert!(e.contains("line 2") && e.contains("psnr"), "{e}");
    std::fs::write(&path, "a,b\n").unwrap();
    assert!(Timeline::read_csv(&path).is_err());
}

#[test]
fn plots_are_written_as_png() {
    let dir = tempfile::tempdir().unwrap();
    let (a, b) = (timeline("a", 1.0, true), timeline("b", 1.3, false));
    let two = dir.path().join("two.png");
    let img = plotted(&two, &[("gtsr", &a), ("pgsr", &b)]);
    assert_eq!(img.dimensions(), (1400, 560));
    // Something other than white background was drawn in both halves.
    let non_white = |x0: u32, x1: u32| {
        img.enumerate_pixels()
            .filter(|(x, _, p)| *x >= x0 && *x < x1 && p.0 != [255, 255, 255])
            .count()
    };
    assert!(non_white(0, 700) > 1000 && non_white(700, 1400) > 1000);
    if let Ok(keep) = std::env::var("GTSR_EVAL_KEEP_PLOT") {
        std::fs::copy(&two, keep).unwrap();
    }
    // A third panel when a series has depth errors.
    let three = dir.path().join("three.png");
    let c = timeline_with("c", 1.0, true, true);
    let img3 = plotted(&three, &[("gtsr", &c)]);
    let drawn = |x0: u32, x1: u32| {
        img3.enumerate_pixels()
            .filter(|(x, _, p)| *x >= x0 && *x < x1 && p.0 != [255, 255, 255])
            .count()
    };
    assert!(drawn(0, 466) > 1000 && drawn(467, 933) > 1000 && drawn(934, 1400) > 1000);
    // The depth-only chamfer and the masks alone are further curves in the chamfer panel, and
    // only there (their values lie inside the chamfer's range: the axis does not move).
    let without: [fn(&mut TimelinePoint); 2] = [
        |p| p.depth_only_chamfer = None,
        |p| p.masks_alone_chamfer = None,
    ];
    for clear in without {
        let mut fewer = c.clone();
        fewer.points.iter_mut().for_each(clear);
        let path = dir.path().join("fewer.png");
        let img_fewer = plotted(&path, &[("gtsr", &fewer)]);
        let differ = |x0, x1| differing_pixels(&img3, &img_fewer, x0, x1);
        assert!(differ(467, 933) > 100, "{}", differ(467, 933));
        assert_eq!((differ(0, 466), differ(934, 1400)), (0, 0));
    }
    let one = dir.path().join("one.png");
    plot_png(&one, &[("pgsr", &b)]).unwrap();
    assert!(std::fs::metadata(&one).unwrap().len() > 1000);
    assert!(plot_png(&dir.path().join("none.png"), &[("empty", &Timeline::new())]).is_err());
}

/// A run's final evaluation is one point at the end, replaced when set again, kept by the
/// CSV, removed for a run that trains on, and drawn as a cross off the curve.
#[test]
fn the_final_evaluation_is_one_point_drawn_off_the_curve() {
    let dir = tempfile::tempdir().unwrap();
    let base = timeline_with("test", 1.0, true, true);
    let mut t = base.clone();
    let last = t.points.last().unwrap().clone();
    t.set_final(TimelinePoint {
        chamfer: Some(0.5),
        ..last.clone()
    });
    t.set_final(TimelinePoint {
        label: "anything".into(),
        ..last.clone()
    });
    assert_eq!(t.points.len(), base.points.len() + 1);
    let end = t.points.last().unwrap();
    assert_eq!(
        (end.label.as_str(), end.chamfer),
        (FINAL_LABEL, last.chamfer)
    );
    let path = dir.path().join("timeline.csv");
    t.write_csv(&path).unwrap();
    assert_eq!(Timeline::read_csv(&path).unwrap(), t);
    // The same values as the curve's last point: the plots differ by the cross alone.
    let (with, without) = (dir.path().join("with.png"), dir.path().join("without.png"));
    let (a, b) = (
        plotted(&with, &[("gtsr", &t)]),
        plotted(&without, &[("gtsr", &base)]),
    );
    let differ = a.pixels().zip(b.pixels()).filter(|(p, q)| p != q).count();
    assert!(differ > 20, "{differ} pixels differ");
    t.drop_final();
    assert_eq!(t, base);
}

#[test]
fn markdown_table_formats_and_escapes() {
    let rows = vec![
        ReportRow {
            method: "GTSR".into(),
            scene: "bear|1".into(),
            chamfer: Some(0.00071),
            chamfer_whole_gt: Some(0.0152),
            hull_blind: Some(0.0481),
            fscore: Some(0.98765),
            depth_err: Some(0.001234),
            depth_bias: Some(-0.0004),
            depth_bias_off_edges: Some(0.00012),
            normal_err_deg: Some(7.26),
            psnr: Some(45.281),
            ssim: Some(0.99612),
            seconds: Some(9000.4),
            gaussians: Some(312_000),
            tile_splats_per_step: Some(42_647.3),
        },
        ReportRow {
            method: "PGSR".into(),
            scene: "bear".into(),
            seconds: Some(125.0),
            ..Default::default()
        },
    ];
    let t = markdown_table(&rows);
    let lines: Vec<&str> = t.lines().collect();
    assert_eq!(lines.len(), 4);
    assert_eq!(
        lines[2],
        "| GTSR | bear\\|1 | 0.71 | 15.20 | 48.10 | 0.988 | 1.23 | -0.40 | +0.12 | 7.3 | 45.28 | 0.9961 | 2:30:00 | \
         312000 | 42.6k |"
    );
    assert_eq!(
        lines[3],
        "| PGSR | bear | - | - | - | - | - | - | - | - | - | - | 2:05 | - | - |"
    );
    assert_eq!(format_duration(59.6), "1:00");
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("r.md");
    write_markdown(&p, &rows).unwrap();
    assert_eq!(std::fs::read_to_string(&p).unwrap(), t);
}

#[test]
fn seed_summary_gives_mean_spread_and_paired_wins() {
    let row =
        |method: &str, scene: &str, d: f64, b: Option<f64>, n: Option<f64>, t: f64| ReportRow {
            method: method.into(),
            scene: scene.into(),
            depth_err: Some(d),
            depth_bias: b,
            normal_err_deg: n,
            psnr: Some(30.0 + t / 60.0 - 1.0),
            ssim: Some(0.99),
            seconds: Some(t),
            ..Default::default()
        };
    let rows = vec![
        (0, row("full", "s", 0.010, Some(-0.001), Some(5.0), 60.0)),
        (0, row("pgsr", "s", 0.011, None, Some(8.0), 60.0)),
        (1, row("full", "s", 0.012, Some(0.001), Some(6.0), 120.0)),
        (1, row("pgsr", "s", 0.011, None, None, 60.0)),
        (2, row("full", "s", 0.014, Some(0.003), Some(7.0), 180.0)),
        (0, row("pgsr", "t", 0.02, None, Some(1.0), 60.0)),
    ];
    let t = seed_summary_table(&rows, "full");
    let lines: Vec<&str> = t.lines().collect();
    assert_eq!(lines.len(), 5, "{t}");
    assert!(lines[0].contains("full ahead on depth err"));
    assert_eq!(
        lines[2],
        "| full | s | 0, 1, 2 | 12.00 ± 2.00 | +1.00 ± 2.00 | 6.0 ± 1.0 | - | 31.00 ± 1.00 | \
         0.9900 ± 0.0000 | 2:00 ± 1:00 | - | - |"
    );
    // pgsr against full, seed by seed: depth 0.010 < 0.011 (seed 0) but 0.012 > 0.011
    // (seed 1); normals only where both have one (seed 0).
    assert_eq!(
        lines[3],
        "| pgsr | s | 0, 1 | 11.00 ± 0.00 | - | 8.0 | - | 30.00 ± 0.00 | 0.9900 ± 0.0000 | \
         1:00 ± 0:00 | 1/2 | 1/1 |"
    );
    // No reference run on scene t.
    assert_eq!(
        lines[4],
        "| pgsr | t | 0 | 20.00 | - | 1.0 | - | 30.00 | 0.9900 | 1:00 | - | - |"
    );
}

/// The legend sits above the curves: chamfer curves that rise to the panel's upper right,
/// where the legend goes, pass under no part of it.
#[test]
fn the_legend_covers_no_curve() {
    let dir = tempfile::tempdir().unwrap();
    let mut t = timeline_with("gtsr", 1.0, true, true);
    for (k, p) in t.points.iter_mut().enumerate() {
        p.chamfer = Some(0.001 * (1.0 + k as f64));
        p.depth_only_chamfer = Some(0.0015 * (1.0 + k as f64));
        p.masks_alone_chamfer = Some(0.004);
    }
    let path = dir.path().join("rising.png");
    let img = plotted(&path, &[("gtsr", &t)]);
    // The chamfer panel is the middle third. In its upper right quarter the legend's frame
    // is the only long black horizontal run: its top and bottom rows and its columns.
    let (w, h) = img.dimensions();
    let (x0, x1) = (w / 3, 2 * w / 3);
    let mut frame_rows = Vec::new();
    let mut columns = (u32::MAX, 0);
    for y in 0..h / 2 {
        let run: Vec<u32> = ((x0 + x1) / 2..x1)
            .filter(|&x| img.get_pixel(x, y).0 == [0, 0, 0])
            .collect();
        if run.len() > 60 {
            frame_rows.push(y);
            columns = (run[0], *run.last().unwrap());
        }
    }
    let (top, bottom) = (*frame_rows.first().unwrap(), *frame_rows.last().unwrap());
    assert!(bottom > top + 20, "no legend frame found ({frame_rows:?})");
    // Inside the frame, the legend's translucent white turns a curve under it pink (the
    // series' red, Palette99's first, at a fifth); its own samples are drawn in full red.
    let pink = (columns.0 + 1..columns.1)
        .flat_map(|x| (top + 1..bottom).map(move |y| (x, y)))
        .filter(|&(x, y)| {
            let [r, g, b] = img.get_pixel(x, y).0.map(i32::from);
            r > 240 && r - g > 20 && r - b > 15
        })
        .count();
    assert_eq!(pink, 0, "{pink} pixels of curve under the legend");
}

/// The completeness split by the masks' blindness travels through the CSV, older logs read
/// without it, and a timeline that has it gets a panel of its own (the plot widens to four
/// panels) whose curves move with the values.
#[test]
fn the_completeness_split_is_kept_and_drawn_in_its_own_panel() {
    let dir = tempfile::tempdir().unwrap();
    let base = timeline_with("gtsr", 1.0, true, true);
    let mut t = base.clone();
    for (k, p) in t.points.iter_mut().enumerate() {
        p.blind_completeness = Some(0.14 - 0.005 * k as f64);
        p.rest_completeness = Some(0.0004 / (1.0 + k as f64));
        p.masks_alone_blind_completeness = Some(0.146);
        p.masks_alone_rest_completeness = Some(0.00054);
        p.mesh_change = (k > 0).then(|| 0.001 / k as f64);
    }
    let path = dir.path().join("timeline.csv");
    t.write_csv(&path).unwrap();
    assert_eq!(Timeline::read_csv(&path).unwrap(), t);
    // A log of the ten columns before the split reads with the split missing.
    std::fs::write(
        &path,
        "iteration,train_seconds,psnr,ssim,chamfer,depth_only_chamfer,masks_alone_chamfer,\
         depth_error,gaussians,label\n1,2,3,0.5,0.01,,0.02,0.03,5,a\n",
    )
    .unwrap();
    let old = Timeline::read_csv(&path).unwrap();
    assert_eq!(
        (old.points[0].masks_alone_chamfer, old.points[0].depth_error),
        (Some(0.02), Some(0.03))
    );
    assert!(old.points[0].blind_completeness.is_none());
    assert!(old.points[0].masks_alone_rest_completeness.is_none());
    assert!(old.points[0].mesh_change.is_none());

    let (with, without) = (dir.path().join("with.png"), dir.path().join("without.png"));
    let (a, b) = (
        plotted(&with, &[("gtsr", &t)]),
        plotted(&without, &[("gtsr", &base)]),
    );
    assert_eq!(b.dimensions(), (1400, 560));
    let (w, h) = a.dimensions();
    assert!(w >= 4 * 465 && h == 560, "{w}x{h}");
    // The third of four panels holds the split: drawn, and changed when a value changes.
    let panel = (w / 2, 3 * w / 4);
    let drawn = a
        .enumerate_pixels()
        .filter(|(x, _, p)| *x >= panel.0 && *x < panel.1 && p.0 != [255, 255, 255])
        .count();
    assert!(drawn > 1000, "{drawn}");
    let mut moved = t.clone();
    moved.points[3].rest_completeness = Some(0.004);
    let path = dir.path().join("moved.png");
    let m = plotted(&path, &[("gtsr", &moved)]);
    let differ = |x0, x1| differing_pixels(&a, &m, x0, x1);
    assert!(
        differ(panel.0, panel.1) > 100,
        "{}",
        differ(panel.0, panel.1)
    );
    assert_eq!((differ(0, w / 2), differ(3 * w / 4, w)), (0, 0));
}
