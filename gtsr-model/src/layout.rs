//! Last-axis slicing and concatenation as products with 0/1 matrices.
//!
//! On the NdArray backend a slice along the last axis is a strided view, and an elementwise op
//! that reads a strided view (or writes a concatenation along the last axis) runs ten to forty
//! times slower than one on contiguous memory. A product with a selection matrix gives the
//! same values in contiguous memory in one pass, and its backward pass is another such
//! product. The values are exact (each output is one input times 1 plus zeros); a non-finite
//! value in one column spreads to its whole row (`0 * inf`), which happens only where a step
//! is already lost.

use std::ops::Range;

use burn::tensor::{Tensor, TensorData};

/// `[c, k]`: column `j` of the result picks column `picks[j]` of a `[m, c]` input.
fn selection(c: usize, picks: impl ExactSizeIterator<Item = usize>, like: &Tensor<2>) -> Tensor<2> {
    let k = picks.len();
    let mut v = vec![0f32; c * k];
    for (j, col) in picks.enumerate() {
        v[col * k + j] = 1.0;
    }
    Tensor::<2>::from_data(TensorData::new(v, [c, k]), &like.device()).cast(like.dtype())
}

/// Columns `picks` of `t` `[m, c]`, in that order (repeats allowed), contiguous.
pub fn pick_cols(t: &Tensor<2>, picks: &[usize]) -> Tensor<2> {
    let c = t.dims()[1];
    t.clone().matmul(selection(c, picks.iter().copied(), t))
}

/// `[c_part, total]`: places a part's columns at `offset` of a `[m, total]` result.
fn placement(c_part: usize, offset: usize, total: usize, like: &Tensor<2>) -> Tensor<2> {
    let mut v = vec![0f32; c_part * total];
    for j in 0..c_part {
        v[j * total + offset + j] = 1.0;
    }
    Tensor::<2>::from_data(TensorData::new(v, [c_part, total]), &like.device()).cast(like.dtype())
}

/// Columns `range` of `t` `[m, c]`, contiguous.
pub fn cols(t: &Tensor<2>, range: Range<usize>) -> Tensor<2> {
    let c = t.dims()[1];
    if range.start == 0 && range.end == c {
        return t.clone();
    }
    t.clone().matmul(selection(c, range, t))
}

/// Column `j` of `t` `[m, c]` as `[m]`.
pub fn col(t: &Tensor<2>, j: usize) -> Tensor<1> {
    let m = t.dims()[0];
    cols(t, j..j + 1).reshape([m])
}

/// Channels `range` of `t` `[h, w, c]`, contiguous.
pub fn channels(t: &Tensor<3>, range: Range<usize>) -> Tensor<3> {
    let [h, w, c] = t.dims();
    let k = range.len();
    cols(&t.clone().reshape([h * w, c]), range).reshape([h, w, k])
}

/// Channel `k` of `t` `[h, w, c]` as `[h, w]`.
pub fn channel(t: &Tensor<3>, k: usize) -> Tensor<2> {
    let [h, w, _] = t.dims();
    channels(t, k..k + 1).reshape([h, w])
}

/// Rows `range` of `t` (its first axis): contiguous when `t` is.
#[allow(clippy::single_range_in_vec_init)] // one range: the first axis only
pub fn rows<const D: usize>(t: &Tensor<D>, range: Range<usize>) -> Tensor<D> {
    t.clone().slice([range])
}

/// `[m, sum c_i]` from parts `[m, c_i]` side by side.
pub fn cat_cols(parts: Vec<Tensor<2>>) -> Tensor<2> {
    let total: usize = parts.iter().map(|p| p.dims()[1]).sum();
    let mut offset = 0;
    let mut out: Option<Tensor<2>> = None;
    for p in parts {
        let c = p.dims()[1];
        let placed = p.clone().matmul(placement(c, offset, total, &p));
        offset += c;
        out = Some(match out {
            Some(acc) => acc + placed,
            None => placed,
        });
    }
    out.expect("at least one part")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    #[allow(deprecated)]
    fn selections_and_concatenations_match_slices_exactly() {
        let d = burn::tensor::Device::ndarray();
        let v: Vec<f32> = (0..2 * 3 * 5).map(|i| i as f32 * 0.37 - 4.0).collect();
        let t = Tensor::<3>::from_data(TensorData::new(v, [2, 3, 5]), &d);
        let host = |t: Tensor<3>| t.into_data().to_vec::<f32>().unwrap();
        assert_eq!(
            host(channels(&t, 1..4)),
            host(t.clone().slice([0..2, 0..3, 1..4]))
        );
        let flat = t.reshape([6, 5]);
        let parts = vec![
            flat.clone().slice([0..6, 0..2]),
            flat.clone().slice([0..6, 2..3]),
            flat.clone().slice([0..6, 3..5]),
        ];
        let host2 = |t: Tensor<2>| t.into_data().to_vec::<f32>().unwrap();
        assert_eq!(host2(cat_cols(parts)), host2(flat.clone()));
        assert_eq!(
            host2(pick_cols(&flat, &[4, 0, 4])),
            host2(Tensor::cat(
                vec![
                    flat.clone().slice([0..6, 4..5]),
                    flat.clone().slice([0..6, 0..1]),
                    flat.clone().slice([0..6, 4..5]),
                ],
                1
            ))
        );
        assert_eq!(
            col(&flat, 4).into_data().to_vec::<f32>().unwrap(),
            flat.slice([0..6, 4..5])
                .reshape([6])
                .into_data()
                .to_vec::<f32>()
                .unwrap()
        );
    }
}
