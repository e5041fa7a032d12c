//! Evaluation of a list of (view, tile) candidates: in parallel, in the given order (nearest
//! to the predicted position first), optionally stopping early once a candidate is decisive.
//!
//! Early stop (a speed-up on top of the paper's area prediction): the nearest candidate is
//! matched alone, then the others in parallel batches; after each batch, if one of them is
//! decisive (at least `early_stop_inliers` inliers and the image
//! centre mapped into the central 60 % of its own tile, so the frame lies well inside that
//! tile), the remaining, farther candidates are skipped; the most inliers among those matched
//! still win. Without it every candidate is matched, exactly as the paper.

use rayon::prelude::*;

use crate::candidate::{Candidate, MatchContext, QueryView, Rejection, evaluate};
use crate::error::Result;
use crate::tile_store::TileStore;
use crate::tiles::MapTiles;

/// What the candidates share.
#[derive(Debug, Clone, Copy)]
pub(crate) struct SearchInput<'a> {
    pub tiles: &'a MapTiles,
    pub store: &'a TileStore,
    pub ctx: MatchContext<'a>,
    pub parallel: bool,
    /// Inliers that make a candidate decisive (see the module docs); `None` never stops early.
    pub early_stop_inliers: Option<usize>,
}

/// Outcome of one pass.
#[derive(Debug, Default)]
pub(crate) struct SearchResult {
    pub best: Option<Candidate>,
    /// Candidates matched.
    pub evaluated: usize,
    /// The most informative rejection seen.
    pub best_rejection: Option<Rejection>,
}

/// Evaluates `jobs` (`(view index, tile index)`) in order.
pub(crate) fn run(
    input: &SearchInput<'_>,
    views: &[&QueryView],
    jobs: &[(usize, usize)],
) -> Result<SearchResult> {
    let mut out = SearchResult::default();
    let batch = match (input.early_stop_inliers, input.parallel) {
        (None, _) => jobs.len().max(1),
        (Some(_), true) => rayon::current_num_threads().max(1),
        (Some(_), false) => 1,
    };
    // The nearest candidate alone first: with a good prediction it is decisive, and matching a
    // second one beside it would only take the core from the tracking thread.
    let first = if input.early_stop_inliers.is_some() {
        1.min(jobs.len())
    } else {
        0
    };
    let (head, tail) = jobs.split_at(first);
    for chunk in std::iter::once(head)
        .filter(|h| !h.is_empty())
        .chain(tail.chunks(batch))
    {
        let eval = |&(v, t): &(usize, usize)| {
            let features = input.store.get(input.tiles, t)?;
            evaluate(
                &input.ctx,
                v,
                views[v],
                t,
                &input.tiles.tiles()[t],
                &features,
            )
        };
        let results: Vec<_> = if input.parallel && chunk.len() > 1 {
            chunk.par_iter().map(eval).collect::<Result<Vec<_>>>()?
        } else {
            chunk.iter().map(eval).collect::<Result<Vec<_>>>()?
        };
        out.evaluated += chunk.len();
        let mut decisive = false;
        for r in results {
            match r {
                Ok(c) => {
                    decisive |= input.early_stop_inliers.is_some_and(|min| {
                        c.inliers.len() >= min
                            && centred_in_its_tile(input.tiles, &c, input.ctx.principal)
                    });
                    if out
                        .best
                        .as_ref()
                        .is_none_or(|b| c.inliers.len() > b.inliers.len())
                    {
                        out.best = Some(c);
                    }
                }
                Err(rej) => {
                    if out
                        .best_rejection
                        .as_ref()
                        .is_none_or(|b| rank(&rej) >= rank(b))
                    {
                        out.best_rejection = Some(rej);
                    }
                }
            }
        }
        if decisive {
            tracing::trace!(evaluated = out.evaluated, of = jobs.len(), "early stop");
            break;
        }
    }
    Ok(out)
}

/// Whether the candidate maps the image centre into the central 60 % of its tile (each axis).
pub(crate) fn centred_in_its_tile(tiles: &MapTiles, c: &Candidate, principal: (f64, f64)) -> bool {
    let (u, v) = c.map_pixel(principal);
    let t = tiles.tiles()[c.tile];
    let (w, h) = tiles.tile_size();
    let (du, dv) = (u - t.x as f64, v - t.y as f64);
    // The central 60 %: central halves of neighbouring tiles (stride half a tile) only touch,
    // so a point on their border would be decisive for neither.
    let inner = |d: f64, len: u32| d >= len as f64 * 0.2 && d <= len as f64 * 0.8;
    inner(du, w) && inner(dv, h)
}

/// How far a rejected candidate got (the most informative rejection is reported).
fn rank(r: &Rejection) -> usize {
    match r {
        Rejection::TooFewMatches { .. } => 1,
        Rejection::NoConsensus { .. } => 2,
        Rejection::TooFewInliers { .. } => 3,
        Rejection::Folded => 4,
        Rejection::Anisotropy { .. } => 5,
        Rejection::Scale { .. } => 6,
    }
}
