//! The root lookup of a disjoint-set forest stored as a parent array, shared by the passes that
//! join connected pieces (blob labelling, the online photometric fit's frame graph).

/// Root of `i`'s set, halving the path on the way (each visited node is pointed at its
/// grandparent), so repeated lookups stay near constant time without a rank array.
pub(crate) fn root(parent: &mut [usize], mut i: usize) -> usize {
    while parent[i] != i {
        parent[i] = parent[parent[i]];
        i = parent[i];
    }
    i
}
