//! The fast path of lines 14–38 of Algorithm 2 on the CPU: which slots the
//! per-slot step ([`super::slot_step`]) must visit, decided for [`CHUNK`]
//! slots at once from each slot's packed bits and its hitbox's code after
//! lines 7–13, and the rates of the others zeroed under the decayed rule.
//! A slot left out is exactly one whose step would return without a
//! counter, a command or a state change (`feedback/tests/chunks.rs`).

use crate::layout::{instance_bits, InstanceHot};

/// Slots decided together by the fast path of lines 14–38 (the bits of a
/// `u64` mask).
pub(super) const CHUNK: usize = 64;

/// Slots whose [`CHUNK`] masks one call of [`busy_masks`] computes.
pub(super) const BLOCK: usize = 8 * CHUNK;

/// `codes` entry of an inactive hitbox (after lines 7–13): the row of
/// [`BUSY`] its instances read.
pub(super) const CODE_INACTIVE: u8 = 0;
/// `codes` entry of an active hitbox.
pub(super) const CODE_ACTIVE: u8 = 1;
/// The code of a hitbox index out of range.
pub(super) const CODE_OUT_OF_RANGE: u8 = 2;

/// Whether lines 14–38 do more than return early for a slot whose low byte
/// of `packed` is `low` in a hitbox with code `code` ([`CODE_INACTIVE`],
/// [`CODE_ACTIVE`], anything else out of range): live, not pinned, and not
/// on the fast path (inactive in an inactive hitbox, or active/omitted and
/// not with a unique BLAS in an active one). Only the state,
/// [`instance_bits::ALIVE`], [`instance_bits::UNIQUE_BLAS`] and
/// [`instance_bits::PINNED`] bits of `low` matter.
pub(super) const fn is_busy(code: u8, low: u32) -> bool {
    let live = low & (instance_bits::ALIVE | instance_bits::PINNED) == instance_bits::ALIVE;
    let state = low & instance_bits::STATE_MASK;
    let inactive = state == 0 || state == instance_bits::STATE_MASK;
    let unique = low & instance_bits::UNIQUE_BLAS != 0;
    let in_range = code == CODE_INACTIVE || code == CODE_ACTIVE;
    let active = code == CODE_ACTIVE;
    let fast = in_range && (active != inactive) && (inactive || !unique);
    live && !fast
}

/// `BUSY[code][p][low]` = [`is_busy`]`(code, low) << p`, for `code` a
/// hitbox code ([`CODE_INACTIVE`], [`CODE_ACTIVE`], [`CODE_OUT_OF_RANGE`]),
/// `p` a slot's place in a group of eight and `low` its low byte of
/// `packed`: the group's eight look-ups ORed give its byte of the busy
/// mask, without shifts.
pub(super) static BUSY: [[[u8; 256]; 8]; 3] = {
    let mut t = [[[0u8; 256]; 8]; 3];
    let mut code = 0;
    while code < 3 {
        let mut p = 0;
        while p < 8 {
            let mut low = 0;
            while low < 256 {
                t[code][p][low] = (is_busy(code as u8, low as u32) as u8) << p;
                low += 1;
            }
            p += 1;
        }
        code += 1;
    }
    t
};

/// The rows of [`BUSY`] for each `u8` code: a look-up by code without a
/// bounds check (codes above 2 never occur; they read the out-of-range
/// rows).
pub(super) static BUSY_ROW: [&[[u8; 256]; 8]; 256] = {
    let mut t = [&BUSY[CODE_OUT_OF_RANGE as usize]; 256];
    t[CODE_INACTIVE as usize] = &BUSY[CODE_INACTIVE as usize];
    t[CODE_ACTIVE as usize] = &BUSY[CODE_ACTIVE as usize];
    t
};

/// Bit `i % 64` of `masks[i / 64]` set for each slot `i` of `block` (at
/// most [`BLOCK`] slots; the masks past its end are 0) that lines 14–38
/// may touch ([`is_busy`]): per slot one look-up of the hitbox's code in
/// `codes` (one per hitbox, then [`CODE_OUT_OF_RANGE`], which every index
/// out of range is clamped to) and one of [`BUSY`], no branch. A clear bit
/// is a slot that lines 14–38 leave alone (no counter, command or state
/// change; rate 0 under the decayed rule), a set bit one for
/// [`super::slot_step`]. Not inlined: a small loop of its own keeps its values in
/// registers.
#[inline(never)]
pub(super) fn busy_masks(block: &[InstanceHot], codes: &[u8], masks: &mut [u64; BLOCK / CHUNK]) {
    let mut bytes = [0u8; BLOCK / 8];
    if let Some(last) = codes.len().checked_sub(1) {
        // (`codes` always ends with the sentinel.)
        let busy = |m: &InstanceHot, p: usize| {
            let rows = BUSY_ROW[usize::from(codes[(m.hitbox as usize).min(last)])];
            rows[p][usize::from(m.packed as u8)]
        };
        let eights = block.chunks_exact(8);
        let tail = eights.remainder();
        let mut k = 0;
        for (e, byte) in eights.zip(bytes.iter_mut()) {
            *byte = (busy(&e[0], 0) | busy(&e[1], 1))
                | (busy(&e[2], 2) | busy(&e[3], 3))
                | ((busy(&e[4], 4) | busy(&e[5], 5)) | (busy(&e[6], 6) | busy(&e[7], 7)));
            k += 1;
        }
        if let Some(byte) = bytes.get_mut(k) {
            *byte = tail.iter().enumerate().fold(0, |b, (p, m)| b | busy(m, p));
        }
    }
    for (mask, eight) in masks.iter_mut().zip(bytes.chunks_exact(8)) {
        let mut le = [0u8; 8];
        le.copy_from_slice(eight);
        *mask = u64::from_le_bytes(le);
    }
}

/// Sets `rates[i]` to 0 where bit `i` of `keep` is clear (at most 64
/// rates): the busy slots' rates are put aside, the chunk zeroed whole
/// (the compiler vectorises it) and they are put back.
#[inline(always)]
pub(super) fn zero_rates_but(rates: &mut [u32], keep: u64) {
    let mut kept = [0u32; CHUNK];
    let mut bits = keep;
    while bits != 0 {
        let i = bits.trailing_zeros() as usize;
        bits &= bits - 1;
        if let (Some(k), Some(&r)) = (kept.get_mut(i), rates.get(i)) {
            *k = r;
        }
    }
    rates.fill(0);
    let mut bits = keep;
    while bits != 0 {
        let i = bits.trailing_zeros() as usize;
        bits &= bits - 1;
        if let (Some(r), Some(&k)) = (rates.get_mut(i), kept.get(i)) {
            *r = k;
        }
    }
}
