//! libtorch is linked and works on CPU: a small convolution's forward and backward pass against
//! values computed by hand.

use tch::{nn, nn::Module, Device, Kind, Tensor};

#[test]
fn conv_forward_and_backward_on_cpu_match_hand_computation() {
    let _timing = crate::support::timed();
    let vs = nn::VarStore::new(Device::Cpu);
    let conv = nn::conv2d(vs.root(), 1, 1, 3, nn::ConvConfig { padding: 1, bias: true, ..Default::default() });
    tch::no_grad(|| {
        let mut vars = vs.variables();
        vars.get_mut("weight").unwrap().copy_(&Tensor::ones([1, 1, 3, 3], (Kind::Float, Device::Cpu)));
        vars.get_mut("bias").unwrap().copy_(&Tensor::from_slice(&[0.5f32]));
    });
    // 4x4 input of ones: a 3x3 box sum with zero padding gives 4 in corners, 6 on edges, 9 inside.
    let x = Tensor::ones([1, 1, 4, 4], (Kind::Float, Device::Cpu)).set_requires_grad(true);
    let y = conv.forward(&x);
    let got: Vec<f32> = Vec::try_from(y.flatten(0, -1)).unwrap();
    let expect: Vec<f32> = [4., 6., 6., 4., 6., 9., 9., 6., 6., 9., 9., 6., 4., 6., 6., 4.].iter().map(|v| v + 0.5).collect();
    assert_eq!(got, expect);

    // d(sum y)/d x at a pixel = number of output pixels whose window covers it = same box-count pattern.
    y.sum(Kind::Float).backward();
    let gx: Vec<f32> = Vec::try_from(x.grad().flatten(0, -1)).unwrap();
    assert_eq!(gx, vec![4., 6., 6., 4., 6., 9., 9., 6., 6., 9., 9., 6., 4., 6., 6., 4.]);
    // d(sum y)/d bias = number of outputs.
    let gb = f64::try_from(vs.variables()["bias"].grad().sum(Kind::Float)).unwrap();
    assert_eq!(gb, 16.0);
}

#[test]
fn an_sgd_step_lowers_a_quadratic_loss() {
    let _timing = crate::support::timed();
    let vs = nn::VarStore::new(Device::Cpu);
    let lin = nn::linear(vs.root(), 3, 1, Default::default());
    let mut opt = nn::OptimizerConfig::build(nn::Sgd::default(), &vs, 0.1).unwrap();
    let x = Tensor::from_slice(&[1.0f32, 2.0, 3.0, -1.0, 0.5, 2.0]).reshape([2, 3]);
    let target = Tensor::from_slice(&[1.0f32, -1.0]).reshape([2, 1]);
    let loss = |lin: &nn::Linear| (lin.forward(&x) - &target).square().mean(Kind::Float);
    let before = f64::try_from(loss(&lin)).unwrap();
    for _ in 0..20 {
        opt.backward_step(&loss(&lin));
    }
    let after = f64::try_from(loss(&lin)).unwrap();
    assert!(after < before * 0.5, "loss {before} -> {after}");
}
