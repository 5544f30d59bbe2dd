//! The GPU engine's pipelines (issue 40): the three GEMM kernels (flat for software adapters,
//! tiles, wide tiles for real GPUs) agree bit for bit and with the exact product within its
//! rounding bound; the pipeline cache on disk never breaks a run (a missing, corrupt, stale or unwritable file falls back to
//! compiling) and parallel writers leave a whole file. On whatever Vulkan adapter exists
//! (lavapipe in CI); without one the tests skip, unless `CBFREACH_REQUIRE_GPU=1`.

use cbfreach::gpu::buffers::Params;
use cbfreach::gpu::disk_cache::{encode, DiskCache, Loaded, Saved};
use cbfreach::gpu::kernels::Gemm;
use cbfreach::gpu::probe::{gemm_on_device, read_back};
use cbfreach::gpu::GpuContext;
use cbfreach::gpu::Precision;
use rand::{Rng, SeedableRng};
use wgpu::util::DeviceExt;

fn context() -> Option<GpuContext> {
    match GpuContext::new() {
        Ok(c) => Some(c),
        Err(e) if std::env::var("CBFREACH_REQUIRE_GPU").as_deref() == Ok("1") => {
            panic!("CBFREACH_REQUIRE_GPU=1 but {e}")
        }
        Err(e) => {
            eprintln!("skipping GPU test: {e}");
            None
        }
    }
}

/// Shapes and options the engine uses: forward layers (`W·X`, `|W|·X`), backward
/// substitutions (`Wᵀ`, with offsets and strides), `|W|·max(X, 0)`, rows and columns off the
/// 4 × 4 blocks, the 64 × 64 tiles and the 64 × 256 wide tiles (depths off 8 and 16), in f32
/// and f64. The three kernels sum in the same order, so they agree bit for bit.
#[test]
fn gemm_kernels_agree_with_each_other_and_the_exact_product() {
    let Some(ctx) = context() else { return };
    let mut precisions = vec![Precision::F32];
    if ctx.has_f64() {
        precisions.push(Precision::F64);
    }
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(40);
    // (rows, inner, cols, trans_w, abs_w, relu_x, w_off, x_off, y_off, extra ldx/ldy)
    let cases = [
        (7, 13, 9, 0, 0, 0, 0, 0, 0, 0),
        (66, 70, 130, 0, 1, 0, 5, 3, 2, 4),
        (2, 100, 36, 1, 0, 1, 11, 0, 7, 1),
        (129, 64, 3, 1, 1, 0, 0, 9, 0, 0),
        (400, 400, 36, 0, 0, 1, 1, 1, 1, 0),
        (65, 19, 257, 0, 1, 1, 2, 1, 3, 2),
        (131, 9, 300, 1, 0, 0, 0, 4, 1, 0),
        (3, 400, 520, 1, 1, 1, 6, 0, 0, 3),
    ];
    for (rows, inner, cols, trans_w, abs_w, relu_x, w_off, x_off, y_off, pad) in cases {
        let p = Params {
            rows,
            inner,
            cols,
            trans_w,
            abs_w,
            relu_x,
            w_off,
            x_off,
            y_off,
            ldx: cols + pad,
            ldy: cols + pad,
            ..Params::default()
        };
        let (r, k, c) = (rows as usize, inner as usize, cols as usize);
        let mut draw =
            |n: usize| -> Vec<f64> { (0..n).map(|_| rng.random_range(-1.0..1.0)).collect() };
        let net = draw(w_off as usize + r * k);
        let x = draw(x_off as usize + k * p.ldx as usize);
        let y0 = vec![7.5; y_off as usize + r * p.ldy as usize];
        for &precision in &precisions {
            let on = |gemm| gemm_on_device(&ctx, precision, gemm, &p, &net, &x, &y0).unwrap();
            let (flat, tiled, wide) = (on(Gemm::Flat), on(Gemm::Tiles), on(Gemm::Wide));
            let what = format!(
                "{rows} × {inner} · {inner} × {cols}, ᵀ {trans_w}, |·| {abs_w}, relu {relu_x}, {}",
                precision.name()
            );
            assert_eq!(flat, tiled, "{what}: flat against tiles");
            assert_eq!(flat, wide, "{what}: flat against wide tiles");
            // The exact product (in f64, of the inputs as the device holds them) against the
            // device's, within the device's rounding bound.
            let (eps, tiny, held): (f64, f64, fn(f64) -> f64) = match precision {
                Precision::F64 => (f64::EPSILON, f64::MIN_POSITIVE, |v| v),
                Precision::F32 => (f32::EPSILON as f64, f32::MIN_POSITIVE as f64, |v| {
                    v as f32 as f64
                }),
            };
            let gamma = |n: usize| (n as f64 + 3.0) * eps;
            for (i, &got) in flat.iter().enumerate() {
                let (ldx, ldy) = (p.ldx as usize, p.ldy as usize);
                let Some(j) = i.checked_sub(y_off as usize).filter(|j| j % ldy < c) else {
                    assert_eq!(got, 7.5, "{what}: entry {i} outside Y was written");
                    continue;
                };
                let (row, col) = (j / ldy, j % ldy);
                let (mut sum, mut mag) = (0.0, 0.0);
                for kk in 0..k {
                    let mut w = held(if trans_w != 0 {
                        net[w_off as usize + kk * r + row]
                    } else {
                        net[w_off as usize + row * k + kk]
                    });
                    if abs_w != 0 {
                        w = w.abs();
                    }
                    let mut v = held(x[x_off as usize + kk * ldx + col]);
                    if relu_x != 0 {
                        v = v.max(0.0);
                    }
                    sum += w * v;
                    mag += (w * v).abs();
                }
                assert!(
                    (got - sum).abs() <= 2.0 * gamma(k) * mag + tiny,
                    "{what}: Y[{row}, {col}] = {got}, exact {sum}"
                );
            }
        }
    }
}

/// A compute pipeline (`ys[i] = 2 xs[i] + 1`) built through `cache`, run on 5 numbers: a run
/// that goes through whatever cache was opened.
fn run_through(ctx: &GpuContext, cache: &DiskCache) -> Vec<f64> {
    let device = &ctx.device;
    let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
    let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some("twice"),
        source: wgpu::ShaderSource::Wgsl(SHADER.into()),
    });
    let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
        label: Some("twice"),
        layout: None,
        module: &module,
        entry_point: Some("twice"),
        compilation_options: Default::default(),
        cache: cache.pipeline_cache(),
    });
    assert!(pollster::block_on(scope.pop()).is_none());
    let xs = [1.0f32, 2.0, 3.0, 4.0, 5.0];
    let buf = |contents: &[u8], usage| {
        device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: None,
            contents,
            usage: wgpu::BufferUsages::STORAGE | usage,
        })
    };
    let input = buf(bytemuck::cast_slice(&xs), wgpu::BufferUsages::empty());
    let output = buf(&[0; 40], wgpu::BufferUsages::COPY_SRC);
    let bind = device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: None,
        layout: &pipeline.get_bind_group_layout(0),
        entries: &[
            wgpu::BindGroupEntry {
                binding: 0,
                resource: input.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: 1,
                resource: output.as_entire_binding(),
            },
        ],
    });
    let mut enc = device.create_command_encoder(&Default::default());
    {
        let mut pass = enc.begin_compute_pass(&Default::default());
        pass.set_pipeline(&pipeline);
        pass.set_bind_group(0, &bind, &[]);
        pass.dispatch_workgroups(1, 1, 1);
    }
    ctx.queue.submit([enc.finish()]);
    // Read as f64 pairs of f32: compare the raw words.
    let words = read_back(ctx, &output, 5).unwrap();
    let out: Vec<f32> = bytemuck::cast_slice(&words)[..5].to_vec();
    out.iter().map(|&v| f64::from(v)).collect()
}

const SHADER: &str = "
@group(0) @binding(0) var<storage, read> xs: array<f32>;
@group(0) @binding(1) var<storage, read_write> ys: array<f32>;
@compute @workgroup_size(8)
fn twice(@builtin(global_invocation_id) id: vec3<u32>) {
    if (id.x < 5u) {
        ys[id.x] = 2.0 * xs[id.x] + 1.0;
    }
}
";

const EXPECTED: [f64; 5] = [3.0, 5.0, 7.0, 9.0, 11.0];

#[test]
fn pipeline_cache_on_disk_falls_back_to_compiling() {
    let Some(ctx) = context() else { return };
    let dir = tempfile::tempdir().unwrap();
    let open = || DiskCache::open_in(&ctx, Some(dir.path()), &[SHADER]);
    let first = open();
    if first.loaded() == &Loaded::Off {
        eprintln!("skipping: the device has no pipeline caches");
        return;
    }
    assert_eq!(first.loaded(), &Loaded::Missing);
    assert_eq!(run_through(&ctx, &first), EXPECTED);
    let Saved::Written(bytes) = first.save() else {
        panic!("first save: {:?}", first.save())
    };
    let path = first.path().unwrap().to_path_buf();
    eprintln!("{}: {bytes} bytes of driver data", ctx.describe());

    // Read back; nothing new to write.
    let second = open();
    assert_eq!(second.loaded(), &Loaded::Read(bytes));
    assert_eq!(run_through(&ctx, &second), EXPECTED);
    assert_eq!(second.save(), Saved::Unchanged);

    // Damaged files: rejected by the checksum, compiled anyway, rewritten whole.
    let good = std::fs::read(&path).unwrap();
    let mut flipped = good.clone();
    *flipped.last_mut().unwrap() ^= 0x40;
    for (what, damaged) in [
        ("flipped", flipped),
        ("truncated", good[..good.len() / 2].to_vec()),
    ] {
        std::fs::write(&path, &damaged).unwrap();
        let c = open();
        assert!(
            matches!(c.loaded(), Loaded::Rejected(_)),
            "{what}: {:?}",
            c.loaded()
        );
        assert_eq!(run_through(&ctx, &c), EXPECTED, "{what}");
        assert!(matches!(c.save(), Saved::Written(_)), "{what}");
        assert_eq!(open().loaded(), &Loaded::Read(bytes), "{what}: rewritten");
    }

    // Stale or foreign data with a valid checksum: wgpu's header names another adapter, or
    // the data is not wgpu's at all; the device refuses it or ignores it, the run compiles.
    let payload = &good[24..];
    let mut foreign = payload.to_vec();
    foreign[17] ^= 0xff; // in wgpu's adapter key (after magic, version, ABI, backend)
    for (what, data) in [
        ("foreign adapter", foreign),
        ("not wgpu's", vec![0x5a; 300]),
    ] {
        std::fs::write(&path, encode(&data)).unwrap();
        let c = open();
        eprintln!("{what}: {:?}", c.loaded());
        assert_eq!(run_through(&ctx, &c), EXPECTED, "{what}");
        assert!(matches!(c.save(), Saved::Written(_)), "{what}");
        ctx.take_error().unwrap();
    }

    // An unwritable directory: the run goes on, the failure is reported.
    let blocked = dir.path().join("blocked");
    std::fs::write(&blocked, b"a file where the directory should be").unwrap();
    let c = DiskCache::open_in(&ctx, Some(&blocked), &[SHADER]);
    assert_eq!(run_through(&ctx, &c), EXPECTED);
    assert!(matches!(c.save(), Saved::Failed(_)), "{:?}", c.save());

    // Parallel writers to one file: each renames a whole file over it, none leaves a temporary.
    std::fs::remove_file(&path).unwrap();
    std::thread::scope(|s| {
        for _ in 0..4 {
            s.spawn(|| {
                let c = open();
                run_through(&ctx, &c);
                c.save();
            });
        }
    });
    assert_eq!(open().loaded(), &Loaded::Read(bytes));
    let leftovers: Vec<_> = std::fs::read_dir(path.parent().unwrap())
        .unwrap()
        .flatten()
        .filter(|e| e.path().extension().is_some_and(|x| x != "bin"))
        .collect();
    assert!(leftovers.is_empty(), "temporary files left: {leftovers:?}");
    ctx.take_error().unwrap();
}
