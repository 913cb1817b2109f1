//! GPU exclusive prefix sum and stable LSD radix sort of `u32` keys with `u32` values, in
//! CubeCL. Burn's own `cumsum` is quadratic on wgpu and its `sort` runs on the host, so the
//! splatting pipeline uses these instead; they are public so that other Burn/CubeCL code can.
//!
//! Every loop in these kernels has a bound fixed at compile time ([`SCAN_BLOCK`],
//! [`SORT_BLOCK`]), so no shader loop depends on the input size (lavapipe and some drivers cap
//! loop trip counts). Sizes up to `u32::MAX` elements are handled by more cubes, not longer
//! loops.

use burn_cubecl::cubecl;
use cubecl::prelude::*;
use cubecl::server::Handle;

/// Threads per cube of the scan and sort kernels.
pub const THREADS: u32 = 256;
/// Elements one cube scans (4 per thread).
pub const SCAN_BLOCK: u32 = 4 * THREADS;
/// Elements one cube ranks per radix pass (4 per thread).
pub const SORT_BLOCK: u32 = 4 * THREADS;
/// Bits per radix digit.
pub const RADIX_BITS: u32 = 4;
const BUCKETS: u32 = 1 << RADIX_BITS;

pub use cubecl::client::Client;

/// In-place exclusive scan of one `SCAN_BLOCK` chunk per cube; the chunk total goes to
/// `sums[cube]`.
#[cube(launch)]
fn scan_blocks(data: &mut [u32], sums: &mut [u32], len: u32, blocks: u32) {
    let cube = CUBE_POS as u32;
    if cube >= blocks {
        terminate!();
    }
    let tid = UNIT_POS;
    let base = cube * SCAN_BLOCK + tid * 4;
    let mut v = Array::<u32>::new(4usize);
    let mut total = 0u32;
    #[unroll]
    for k in 0..4u32 {
        let i = base + k;
        let x = if i < len { data[i as usize] } else { 0u32 };
        v[k as usize] = total;
        total += x;
    }
    let mut tmp = Shared::<[u32]>::new_slice(THREADS as usize);
    tmp[tid as usize] = total;
    sync_cube();
    // Hillis-Steele inclusive scan of the per-thread totals.
    #[unroll]
    for s in 0..8u32 {
        let d = 1u32 << s;
        let mut x = tmp[tid as usize];
        if tid >= d {
            x += tmp[(tid - d) as usize];
        }
        sync_cube();
        tmp[tid as usize] = x;
        sync_cube();
    }
    let excl = tmp[tid as usize] - total;
    #[unroll]
    for k in 0..4u32 {
        let i = base + k;
        if i < len {
            data[i as usize] = excl + v[k as usize];
        }
    }
    if tid == THREADS - 1 {
        sums[cube as usize] = tmp[tid as usize];
    }
}

/// Adds the scanned chunk totals back.
#[cube(launch)]
fn scan_add(data: &mut [u32], sums: &[u32], len: u32) {
    let i = ABSOLUTE_POS as u32;
    if i < len {
        data[i as usize] += sums[(i / SCAN_BLOCK) as usize];
    }
}

/// Fills `data[0..len]` with `value`.
#[cube(launch)]
pub fn fill_u32(data: &mut [u32], value: u32, len: u32) {
    let i = ABSOLUTE_POS as u32;
    if i < len {
        data[i as usize] = value;
    }
}

/// `dst[0] = src[index]`.
#[cube(launch)]
fn copy_one(src: &[u32], dst: &mut [u32], index: u32) {
    if UNIT_POS == 0 {
        dst[0] = src[index as usize];
    }
}

/// The kernel argument for the first `len` elements of `data`.
pub(crate) fn buffer_arg(data: &Handle, len: u32) -> BufferArg {
    // SAFETY: every caller passes a buffer holding at least `len` 4-byte elements.
    unsafe { BufferArg::from_raw_parts(data.clone(), len as usize) }
}

/// Launches `fill_u32`.
pub fn fill(client: &Client, data: &Handle, value: u32, len: u32) {
    if len == 0 {
        return;
    }
    let (count, dim) = elementwise_flat(len);
    fill_u32::launch(client, count, dim, buffer_arg(data, len), value, len);
}

/// Zeroes `data[0..len]` (of any 4-byte element type: `0.0f32` is all zero bits).
pub fn zero(client: &Client, data: &Handle, len: u32) {
    fill(client, data, 0, len);
}

/// A grid of `cubes` cubes: along x up to the 65,535 a dispatch dimension allows, then rows
/// along y. Kernels index with the linear `CUBE_POS` / `ABSOLUTE_POS` and skip past the end.
pub fn grid(cubes: u32) -> CubeCount {
    let cubes = cubes.max(1);
    if cubes <= 65_535 {
        CubeCount::Static(cubes, 1, 1)
    } else {
        CubeCount::Static(65_535, cubes.div_ceil(65_535), 1)
    }
}

/// One thread per element, [`THREADS`] per cube, over [`grid`].
pub(crate) fn elementwise_flat(len: u32) -> (CubeCount, CubeDim) {
    (grid(len.div_ceil(THREADS)), CubeDim::new_1d(THREADS))
}

/// Exclusive prefix sum of `data[0..len]` in place, on the device, with no host readback.
/// Chunks of [`SCAN_BLOCK`] are scanned by one cube each; the chunk totals are scanned
/// recursively and added back.
pub fn exclusive_scan(client: &Client, data: &Handle, len: u32) {
    if len == 0 {
        return;
    }
    let blocks = len.div_ceil(SCAN_BLOCK);
    let sums = client.empty(blocks as usize * 4);
    scan_blocks::launch(
        client,
        grid(blocks),
        CubeDim::new_1d(THREADS),
        buffer_arg(data, len),
        buffer_arg(&sums, blocks),
        len,
        blocks,
    );
    if blocks > 1 {
        exclusive_scan(client, &sums, blocks);
        let (count, dim) = elementwise_flat(len);
        scan_add::launch(
            client,
            count,
            dim,
            buffer_arg(data, len),
            buffer_arg(&sums, blocks),
            len,
        );
    }
}

/// Reads `data[index]` back to the host (one 4-byte readback).
pub fn read_u32(client: &Client, data: &Handle, len: u32, index: u32) -> u32 {
    let one = client.empty(4);
    copy_one::launch(
        client,
        CubeCount::Static(1, 1, 1),
        CubeDim::new_1d(1),
        buffer_arg(data, len),
        buffer_arg(&one, 1),
        index,
    );
    let bytes = client.read_one_unchecked(one);
    u32::from_le_bytes([bytes[0], bytes[1], bytes[2], bytes[3]])
}

/// Loads the digits of one `SORT_BLOCK` chunk into shared memory (`BUCKETS` past the end).
#[cube]
fn load_digits(keys: &[u32], digits: &mut Shared<[u32]>, len: u32, shift: u32) {
    let tid = UNIT_POS;
    let base = CUBE_POS as u32 * SORT_BLOCK;
    #[unroll]
    for k in 0..4u32 {
        let local = k * THREADS + tid;
        let i = base + local;
        digits[local as usize] = if i < len {
            (keys[i as usize] >> shift) & (BUCKETS - 1)
        } else {
            BUCKETS
        };
    }
    sync_cube();
}

/// Per chunk, the count of each digit: `hist[digit * cubes + cube]` (digit-major, so that an
/// exclusive scan of `hist` gives every chunk's first output slot per digit in stable order).
#[cube(launch)]
fn radix_count(keys: &[u32], hist: &mut [u32], len: u32, shift: u32, chunks: u32) {
    if CUBE_POS as u32 >= chunks {
        terminate!();
    }
    let mut digits = Shared::<[u32]>::new_slice(SORT_BLOCK as usize);
    load_digits(keys, &mut digits, len, shift);
    let tid = UNIT_POS;
    if tid < BUCKETS {
        let mut count = 0u32;
        for j in 0..SORT_BLOCK {
            if digits[j as usize] == tid {
                count += 1;
            }
        }
        hist[(tid * chunks + CUBE_POS as u32) as usize] = count;
    }
}

/// Scatters one chunk to its sorted slots. Thread `d < BUCKETS` walks the chunk in order and
/// hands out consecutive slots to the elements with digit `d`, which keeps the sort stable.
#[cube(launch)]
fn radix_scatter(
    keys_in: &[u32],
    vals_in: &[u32],
    offsets: &[u32],
    keys_out: &mut [u32],
    vals_out: &mut [u32],
    len: u32,
    shift: u32,
    chunks: u32,
) {
    if CUBE_POS as u32 >= chunks {
        terminate!();
    }
    let mut digits = Shared::<[u32]>::new_slice(SORT_BLOCK as usize);
    load_digits(keys_in, &mut digits, len, shift);
    let mut slot = Shared::<[u32]>::new_slice(SORT_BLOCK as usize);
    let tid = UNIT_POS;
    if tid < BUCKETS {
        let mut next = offsets[(tid * chunks + CUBE_POS as u32) as usize];
        for j in 0..SORT_BLOCK {
            if digits[j as usize] == tid {
                slot[j as usize] = next;
                next += 1;
            }
        }
    }
    sync_cube();
    let base = CUBE_POS as u32 * SORT_BLOCK;
    #[unroll]
    for k in 0..4u32 {
        let local = k * THREADS + tid;
        let i = base + local;
        if i < len {
            let s = slot[local as usize];
            keys_out[s as usize] = keys_in[i as usize];
            vals_out[s as usize] = vals_in[i as usize];
        }
    }
}

/// Stable sort of `keys[0..len]` (and `vals` alongside) by their low `bits` bits, on the
/// device. Returns the handles holding the sorted keys and values (either the inputs or the
/// scratch buffers, by the parity of the pass count); the other pair is scratch.
pub fn radix_sort(
    client: &Client,
    keys: Handle,
    vals: Handle,
    len: u32,
    bits: u32,
) -> (Handle, Handle) {
    if len <= 1 || bits == 0 {
        return (keys, vals);
    }
    let chunks = len.div_ceil(SORT_BLOCK);
    let hist_len = chunks * BUCKETS;
    let hist = client.empty(hist_len as usize * 4);
    let mut src = (keys, vals);
    let mut dst = (
        client.empty(len as usize * 4),
        client.empty(len as usize * 4),
    );
    let passes = bits.min(32).div_ceil(RADIX_BITS);
    for pass in 0..passes {
        let shift = pass * RADIX_BITS;
        radix_count::launch(
            client,
            grid(chunks),
            CubeDim::new_1d(THREADS),
            buffer_arg(&src.0, len),
            buffer_arg(&hist, hist_len),
            len,
            shift,
            chunks,
        );
        exclusive_scan(client, &hist, hist_len);
        radix_scatter::launch(
            client,
            grid(chunks),
            CubeDim::new_1d(THREADS),
            buffer_arg(&src.0, len),
            buffer_arg(&src.1, len),
            buffer_arg(&hist, hist_len),
            buffer_arg(&dst.0, len),
            buffer_arg(&dst.1, len),
            len,
            shift,
            chunks,
        );
        std::mem::swap(&mut src, &mut dst);
    }
    src
}

/// Number of bits needed to hold values up to `max_value`.
pub fn bits_for(max_value: u32) -> u32 {
    32 - max_value.leading_zeros()
}

fn upload(client: &Client, v: &[u32]) -> Handle {
    let bytes: Vec<u8> = v.iter().flat_map(|x| x.to_le_bytes()).collect();
    if bytes.is_empty() {
        client.empty(4)
    } else {
        client.create_from_slice(&bytes)
    }
}

/// Reads `len` `u32`s of a device buffer back to the host.
pub fn download(client: &Client, h: Handle, len: usize) -> Vec<u32> {
    if len == 0 {
        return Vec::new();
    }
    let bytes = client.read_one_unchecked(h);
    bytes[..len * 4]
        .chunks_exact(4)
        .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect()
}

/// Host convenience around [`radix_sort`]: uploads `keys` and `vals`, sorts them stably by the
/// low `bits` bits of the keys on the device, and reads both back.
pub fn sort_pairs(client: &Client, keys: &[u32], vals: &[u32], bits: u32) -> (Vec<u32>, Vec<u32>) {
    assert_eq!(
        keys.len(),
        vals.len(),
        "sort_pairs: keys and values differ in length"
    );
    let n = keys.len();
    let (k, v) = radix_sort(
        client,
        upload(client, keys),
        upload(client, vals),
        n as u32,
        bits,
    );
    (download(client, k, n), download(client, v, n))
}

/// Host convenience around [`exclusive_scan`]: the exclusive prefix sum (wrapping) of `data`,
/// computed on the device.
pub fn exclusive_scan_host(client: &Client, data: &[u32]) -> Vec<u32> {
    let h = upload(client, data);
    exclusive_scan(client, &h, data.len() as u32);
    download(client, h, data.len())
}
